//! Finding and loading Intel Open Image Denoise at run time, and the dozen C functions of
//! its API that the denoiser calls (OIDN 2.x `include/OpenImageDenoise/oidn.h`).
//!
//! Loading at run time (libloading) rather than linking keeps the library optional: a
//! build needs no OIDN, and only a request to denoise fails when it is absent.

use std::ffi::{c_char, c_int, c_void};
use std::path::{Path, PathBuf};

use libloading::Library;

/// The entry library's file name (its SONAME): OIDN 2.x.
pub(super) const LIBRARY: &str = "libOpenImageDenoise.so.2";

/// What a `Missing` error tells the user to do.
pub(super) const INSTALL_HINT: &str = "run `bash scripts/oidn.sh` (downloads Intel Open Image \
     Denoise 2.5.1 from PyPI's pyoidn wheel) or set GLIMPSE_OIDN_DIR to a folder holding \
     libOpenImageDenoise.so.2";

/// Opaque `OIDNDevice` and `OIDNFilter` handles.
pub(super) type DeviceHandle = *mut c_void;
pub(super) type FilterHandle = *mut c_void;

// oidn.h enums, passed as C `int` (their underlying type on every ABI OIDN supports).
pub(super) const DEVICE_TYPE_CPU: c_int = 1;
pub(super) const FORMAT_FLOAT3: c_int = 3;
pub(super) const QUALITY_FAST: c_int = 4;
pub(super) const QUALITY_BALANCED: c_int = 5;
pub(super) const QUALITY_HIGH: c_int = 6;
pub(super) const ERROR_NONE: c_int = 0;
pub(super) const ERROR_CANCELLED: c_int = 6;

/// `OIDNProgressMonitorFunction`: called as the filter executes; `false` aborts it.
pub(super) type ProgressMonitor = unsafe extern "C" fn(*mut c_void, f64) -> bool;

/// The functions of `oidn.h` that Glimpse calls, resolved from a loaded library. Each
/// pointer is valid while `_libraries` stays loaded, which is as long as `Api` lives.
pub(super) struct Api {
    pub new_device: unsafe extern "C" fn(c_int) -> DeviceHandle,
    pub set_device_bool: unsafe extern "C" fn(DeviceHandle, *const c_char, bool),
    pub set_device_int: unsafe extern "C" fn(DeviceHandle, *const c_char, c_int),
    pub get_device_int: unsafe extern "C" fn(DeviceHandle, *const c_char) -> c_int,
    pub commit_device: unsafe extern "C" fn(DeviceHandle),
    pub get_device_error: unsafe extern "C" fn(DeviceHandle, *mut *const c_char) -> c_int,
    pub release_device: unsafe extern "C" fn(DeviceHandle),
    pub new_filter: unsafe extern "C" fn(DeviceHandle, *const c_char) -> FilterHandle,
    #[allow(clippy::type_complexity)]
    pub set_shared_filter_image: unsafe extern "C" fn(
        FilterHandle,
        *const c_char,
        *mut c_void,
        c_int,
        usize,
        usize,
        usize,
        usize,
        usize,
    ),
    pub set_filter_bool: unsafe extern "C" fn(FilterHandle, *const c_char, bool),
    pub set_filter_int: unsafe extern "C" fn(FilterHandle, *const c_char, c_int),
    pub set_filter_float: unsafe extern "C" fn(FilterHandle, *const c_char, f32),
    pub set_filter_progress_monitor:
        unsafe extern "C" fn(FilterHandle, Option<ProgressMonitor>, *mut c_void),
    pub commit_filter: unsafe extern "C" fn(FilterHandle),
    pub execute_filter: unsafe extern "C" fn(FilterHandle),
    pub release_filter: unsafe extern "C" fn(FilterHandle),
    /// The file the entry library was loaded from (or its bare name, via the system loader).
    pub path: PathBuf,
    /// Dependencies first, entry library last; kept loaded for the function pointers.
    _libraries: Vec<Library>,
}

/// Where to look for the library, in order. Built from explicit inputs so that tests can
/// search places of their choosing ([`SearchPlan::from_environment`] is what runs).
#[derive(Clone, Debug)]
pub(super) struct SearchPlan {
    /// Folders, each with why it is searched ("GLIMPSE_OIDN_DIR", "next to the executable").
    pub folders: Vec<(PathBuf, &'static str)>,
    /// The name handed to the system loader last (LD_LIBRARY_PATH, ldconfig), if any.
    pub system: Option<String>,
}

impl SearchPlan {
    /// The order of the module doc: `$GLIMPSE_OIDN_DIR` (the folder or its `lib/`) and
    /// nothing else when it is set (what a person names is what is used: a wrong folder
    /// is an error, not a silent fallback to another library); else the checkout's
    /// `target/oidn/lib` (where `scripts/oidn.sh` installs, right for `cargo run` and
    /// `cargo test`), the executable's folder and its `../oidn/lib`, `../../oidn/lib` (so
    /// `target/release/glimpse` and `target/debug/deps/*` find `target/oidn/lib` under any
    /// target directory), then the system loader.
    pub fn new(env_dir: Option<PathBuf>, checkout: &Path, exe: Option<&Path>) -> Self {
        let mut folders = Vec::new();
        if let Some(dir) = env_dir.filter(|d| !d.as_os_str().is_empty()) {
            let lib = dir.join("lib");
            folders.push((dir, "GLIMPSE_OIDN_DIR"));
            folders.push((lib, "GLIMPSE_OIDN_DIR/lib"));
            return Self {
                folders,
                system: None,
            };
        }
        folders.push((
            checkout.join("target/oidn/lib"),
            "the checkout's target/oidn/lib",
        ));
        if let Some(bin) = exe.and_then(Path::parent) {
            folders.push((bin.to_path_buf(), "the executable's folder"));
            folders.push((bin.join("../oidn/lib"), "beside the executable"));
            folders.push((bin.join("../../oidn/lib"), "beside the executable"));
        }
        Self {
            folders,
            system: Some(LIBRARY.to_owned()),
        }
    }

    /// The plan for this process: reads `GLIMPSE_OIDN_DIR` and the executable's path.
    pub fn from_environment() -> Self {
        let exe = std::env::current_exe().ok();
        Self::new(
            std::env::var_os("GLIMPSE_OIDN_DIR").map(PathBuf::from),
            Path::new(env!("CARGO_MANIFEST_DIR")),
            exe.as_deref(),
        )
    }

    /// Loads the first library found; on failure, one line per place searched saying
    /// what was there (absent, or present but refused by the loader and why).
    pub fn load(&self) -> Result<Api, Vec<String>> {
        let mut searched = Vec::new();
        for (folder, why) in &self.folders {
            let entry = folder.join(LIBRARY);
            if !entry.is_file() {
                searched.push(format!("{} ({why}): not found", entry.display()));
                continue;
            }
            match load_folder(folder).and_then(|libs| Api::resolve(libs, entry.clone())) {
                Ok(api) => return Ok(api),
                Err(e) => searched.push(format!(
                    "{} ({why}): found but not loaded: {e}",
                    entry.display()
                )),
            }
        }
        if let Some(name) = &self.system {
            // SAFETY: loading runs the library's initialisers; OIDN's are plain C++ statics.
            match unsafe { Library::new(name) }
                .and_then(|lib| Api::resolve(vec![lib], PathBuf::from(name)))
            {
                Ok(api) => return Ok(api),
                Err(e) => searched.push(format!("{name} (system loader): {e}")),
            }
        }
        Err(searched)
    }
}

/// Loads a folder's TBB and OIDN core by full path before the entry library. The wheel's
/// libraries carry RPATH `$ORIGIN/../lib`, which finds them only in a folder named `lib`;
/// once loaded, the dynamic loader matches the entry library's NEEDED entries by SONAME,
/// so any folder works. (The core finds its CPU device module beside itself.)
fn load_folder(folder: &Path) -> Result<Vec<Library>, libloading::Error> {
    let mut names: Vec<PathBuf> = Vec::new();
    let tbb = folder.join("libtbb.so.12");
    if tbb.is_file() {
        names.push(tbb);
    }
    if let Ok(entries) = std::fs::read_dir(folder) {
        let mut cores: Vec<PathBuf> = entries
            .filter_map(Result::ok)
            .map(|e| e.path())
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("libOpenImageDenoise_core.so"))
            })
            .collect();
        // The longest name is the fully versioned file, the one the entry library NEEDs.
        cores.sort_by_key(|p| p.as_os_str().len());
        names.extend(cores.pop());
    }
    names.push(folder.join(LIBRARY));
    let mut libraries = Vec::with_capacity(names.len());
    for name in names {
        // SAFETY: as in `SearchPlan::load`.
        libraries.push(unsafe { Library::new(&name) }?);
    }
    Ok(libraries)
}

impl Api {
    /// Resolves every function from the last (entry) library of `libraries`.
    fn resolve(libraries: Vec<Library>, path: PathBuf) -> Result<Self, libloading::Error> {
        let lib = libraries.last().expect("at least the entry library");
        // SAFETY: each type below is the C prototype of the same name in OIDN 2.x's oidn.h;
        // the pointers are copied out but stay valid because `_libraries` keeps them loaded.
        unsafe {
            Ok(Self {
                new_device: *lib.get(b"oidnNewDevice\0")?,
                set_device_bool: *lib.get(b"oidnSetDeviceBool\0")?,
                set_device_int: *lib.get(b"oidnSetDeviceInt\0")?,
                get_device_int: *lib.get(b"oidnGetDeviceInt\0")?,
                commit_device: *lib.get(b"oidnCommitDevice\0")?,
                get_device_error: *lib.get(b"oidnGetDeviceError\0")?,
                release_device: *lib.get(b"oidnReleaseDevice\0")?,
                new_filter: *lib.get(b"oidnNewFilter\0")?,
                set_shared_filter_image: *lib.get(b"oidnSetSharedFilterImage\0")?,
                set_filter_bool: *lib.get(b"oidnSetFilterBool\0")?,
                set_filter_int: *lib.get(b"oidnSetFilterInt\0")?,
                set_filter_float: *lib.get(b"oidnSetFilterFloat\0")?,
                set_filter_progress_monitor: *lib.get(b"oidnSetFilterProgressMonitorFunction\0")?,
                commit_filter: *lib.get(b"oidnCommitFilter\0")?,
                execute_filter: *lib.get(b"oidnExecuteFilter\0")?,
                release_filter: *lib.get(b"oidnReleaseFilter\0")?,
                path,
                _libraries: libraries,
            })
        }
    }
}
