//! The denoiser stage: Intel Open Image Denoise 2.x (the `RT` filter) on a linear HDR
//! image, with auxiliary albedo and normal images from the tracer's first hits.
//!
//! The library is loaded at run time (`library`), so a machine without it builds and runs
//! every mode that does not denoise, and one that asks for denoising gets
//! [`DenoiseError::Missing`] naming where it looked and how to add it
//! (`bash scripts/oidn.sh`). Search order: `$GLIMPSE_OIDN_DIR` (or its `lib/`) alone when
//! it is set; else the checkout's `target/oidn/lib`, the executable's folder and its
//! `../oidn/lib` and `../../oidn/lib`, then the system loader.
//!
//! Inputs are sanitised before they reach OIDN: a NaN or infinite pixel makes the network
//! paint a large white blotch (RenderKit/oidn#210, the maintainer's advice is to clamp in
//! the renderer), and the output is checked as well, so no non-finite value comes back.

mod library;
#[cfg(test)]
mod tests;

use std::ffi::{c_char, c_void, CStr};
use std::path::Path;
use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError, TryLockError};

use crate::cancel::CancelToken;
use crate::raster::{LinearImage, Rgb};
use library::{Api, DeviceHandle, FilterHandle, SearchPlan};

// OIDN reads our pixels in place as FLOAT3 with a 12-byte stride; glam's `Vec3` (not
// `Vec3A`) is three packed f32s.
const _: () = assert!(std::mem::size_of::<Rgb>() == 12);

/// The brightest radiance passed to OIDN, in scene units; `+Inf` becomes this. Measured
/// on a 32x32 image of 0.5 with one bright pixel, High, automatic `inputScale`: up to 1e6
/// the rest of the picture stays within 6% of 0.5; at 1e10 all of it came back at ~2.4
/// (a picture-wide blotch). A pixel this bright is white on any display anyway; only
/// the denoised copy is clipped, never the render.
pub const MAX_RADIANCE: f32 = 1.0e6;

/// The smallest side handed to OIDN. Its network needs neighbours: measured on a flat
/// 0.5 image, a 1x1 came back at 0.09 and a 400x1 at 0.27 (High), 32x32 at 0.5. Smaller
/// images are mirrored out to this size first and the result cropped back.
const MIN_SIDE: u32 = 32;

/// The longest side handed to OIDN: it refuses a 100000-pixel side ("image size is too
/// large") and took 65536; longer images are denoised in strips.
const MAX_SIDE: u32 = 32768;

/// Context on each side of a strip: more than the network's receptive field, so a strip's
/// kept middle is what one run over the whole image would give. Strips start on
/// multiples of 16 (this and [`MAX_SIDE`] are), the grid of the network's downsampling:
/// a run shifted off it gives a (slightly) different picture.
const STRIP_OVERLAP: u32 = 256;

/// OIDN's `quality` parameter: a streamed frame can take `Fast`, the final one `High`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    Fast,
    Balanced,
    High,
}

/// How one denoise runs, besides its images.
#[derive(Clone, Debug)]
pub struct Run {
    pub quality: Quality,
    /// Multiplies the colour so that 1.0 means 100 cd/m² (OIDN's HDR convention); `None`
    /// lets OIDN pick it per image.
    pub input_scale: Option<f32>,
    /// Aborts the filter from OIDN's progress monitor, which it calls between the pieces
    /// of its work: a cancel ends even a 4096² denoise within a fraction of a second.
    pub cancel: CancelToken,
    /// OIDN's `maxMemoryMB`: a filter that would need more scratch memory works in
    /// overlapping tiles instead (same picture up to the tiles' seams, api.md), so that a
    /// job's memory does not grow with its image past what the operator allows. `None`
    /// is OIDN's own default, which grows with the image (≈ 0.8 KB a pixel measured).
    pub max_memory_mb: Option<u32>,
}

impl Run {
    /// At `quality`, OIDN's own scale and memory, never cancelled.
    #[must_use]
    pub fn new(quality: Quality) -> Self {
        Self {
            quality,
            input_scale: None,
            cancel: CancelToken::new(),
            max_memory_mb: None,
        }
    }
}

/// The auxiliary images of the `RT` filter, the same size as the colour image.
#[derive(Clone, Copy, Debug)]
pub struct Aux<'a> {
    /// First non-delta hit's albedo, each channel in [0, 1].
    pub albedo: &'a LinearImage,
    /// First non-delta hit's shading normal, each component in [-1, 1] (zero on a miss).
    pub normal: &'a LinearImage,
    /// Whether both are free of Monte Carlo noise (OIDN's `cleanAux`).
    pub clean: bool,
}

/// Why a picture could not be denoised.
#[derive(Debug, thiserror::Error)]
pub enum DenoiseError {
    /// No loadable OIDN 2.x: one line per place searched, in order.
    #[error(
        "Intel Open Image Denoise 2.x is needed to denoise and was not found: {}. \
         Searched, in order:\n  {}",
        library::INSTALL_HINT,
        .searched.join("\n  ")
    )]
    Missing { searched: Vec<String> },
    /// OIDN reported an error (its own message, with what we were doing).
    #[error("Intel Open Image Denoise failed {0}")]
    Library(String),
    /// An auxiliary image whose size differs from the colour image's.
    #[error(
        "the {what} image is {}x{} but the colour image is {}x{}; \
         auxiliary images must have the colour image's size",
        .aux.0, .aux.1, .color.0, .color.1
    )]
    SizeMismatch {
        what: &'static str,
        color: (u32, u32),
        aux: (u32, u32),
    },
    /// `input_scale` that is not a finite number above zero.
    #[error("input_scale must be a finite number above 0, got {0}")]
    InputScale(f32),
    /// The run's cancel token fired (before, or while OIDN was executing).
    #[error("cancelled")]
    Cancelled,
}

/// An `OIDNDevice` handle. OIDN allows a device to be used from any thread, one call at a
/// time; the `Mutex` in [`Denoiser`] provides the one at a time.
struct Device(DeviceHandle);

// SAFETY: the handle is only used under `Denoiser::device`'s lock (see `Device`).
unsafe impl Send for Device {}

/// One OIDN CPU device, shared by the process.
pub struct Denoiser {
    api: Api,
    device: Mutex<Device>,
    /// OIDN's `version` device parameter, e.g. 20501 for 2.5.1.
    version: i32,
}

/// The parameters of one `RT` filter run.
struct Params<'a> {
    hdr: bool,
    clean_aux: bool,
    run: &'a Run,
}

impl Denoiser {
    /// The process's one denoiser: loads the library and commits the CPU device once.
    /// A failure is not remembered, so installing the library later (scripts/oidn.sh)
    /// works without a restart.
    pub fn shared() -> Result<&'static Denoiser, DenoiseError> {
        static SHARED: OnceLock<Denoiser> = OnceLock::new();
        static LOADING: Mutex<()> = Mutex::new(());
        if let Some(d) = SHARED.get() {
            return Ok(d);
        }
        let _one_loader = LOADING.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(d) = SHARED.get() {
            return Ok(d);
        }
        let denoiser = Self::open(&SearchPlan::from_environment())?;
        Ok(SHARED.get_or_init(|| denoiser))
    }

    /// Loads the library found by `plan` and commits a CPU device on it.
    fn open(plan: &SearchPlan) -> Result<Self, DenoiseError> {
        let api = plan
            .load()
            .map_err(|searched| DenoiseError::Missing { searched })?;
        // SAFETY: calls into OIDN with a device handle it just returned (checked non-null).
        unsafe {
            let handle = (api.new_device)(library::DEVICE_TYPE_CPU);
            let mut denoiser = Self {
                device: Mutex::new(Device(handle)),
                version: 0,
                api,
            };
            if handle.is_null() {
                denoiser.check(handle, "creating the CPU device")?;
                return Err(DenoiseError::Library(
                    "creating the CPU device: no device and no error".into(),
                ));
            }
            // Not pinning OIDN's (TBB's) threads to cores: the tracer's rayon threads run
            // on the same cores, and pinned threads cannot move away from them (api.md,
            // "setAffinity"). Its thread count follows rayon's, which honours
            // RAYON_NUM_THREADS; by default both use every core.
            (denoiser.api.set_device_bool)(handle, c"setAffinity".as_ptr(), false);
            let threads = i32::try_from(rayon::current_num_threads()).unwrap_or(0);
            (denoiser.api.set_device_int)(handle, c"numThreads".as_ptr(), threads);
            (denoiser.api.commit_device)(handle);
            denoiser.check(handle, "committing the CPU device")?;
            let version = (denoiser.api.get_device_int)(handle, c"version".as_ptr());
            if version / 10000 != 2 {
                return Err(DenoiseError::Library(format!(
                    "at {}: version {} found, Glimpse needs 2.x",
                    denoiser.api.path.display(),
                    version_string(version)
                )));
            }
            denoiser.version = version;
            Ok(denoiser)
        }
    }

    /// The loaded library's version, e.g. "2.5.1".
    #[must_use]
    pub fn version(&self) -> String {
        version_string(self.version)
    }

    /// The file the library was loaded from (a bare name if the system loader found it).
    #[must_use]
    pub fn library_path(&self) -> &Path {
        &self.api.path
    }

    /// `color` denoised as `run` says.
    ///
    /// With `aux`, albedo and normal guide the filter; `aux.clean` sets OIDN's `cleanAux`
    /// (only for noise-free images, else their noise survives: api.md). Non-finite or
    /// negative radiance becomes 0 and anything above [`MAX_RADIANCE`] is clamped to it
    /// first; the output is finite and non-negative.
    pub fn denoise(
        &self,
        color: &LinearImage,
        aux: Option<&Aux<'_>>,
        run: &Run,
    ) -> Result<LinearImage, DenoiseError> {
        if let Some(s) = run.input_scale {
            if !(s.is_finite() && s > 0.0) {
                return Err(DenoiseError::InputScale(s));
            }
        }
        let input = color.map(|&c| {
            c.map(|v| {
                if v.is_nan() {
                    0.0
                } else {
                    v.clamp(0.0, MAX_RADIANCE)
                }
            })
        });
        let guides = match aux {
            Some(a) => Some((
                sanitized_albedo(a.albedo, color)?,
                sanitized_normal(a.normal, color)?,
            )),
            None => None,
        };
        let mut inputs = vec![(c"color", &input)];
        if let Some((albedo, normal)) = &guides {
            inputs.push((c"albedo", albedo));
            inputs.push((c"normal", normal));
        }
        let params = Params {
            hdr: true,
            clean_aux: aux.is_some_and(|a| a.clean),
            run,
        };
        let mut out = self.run(&inputs, &params)?;
        for p in out.pixels_mut() {
            *p = p.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 });
        }
        Ok(out)
    }

    /// Noisy auxiliary images made noise-free by OIDN (each through its own `RT` filter,
    /// api.md's final-frame recipe), to pass afterwards as `Aux { clean: true, .. }`:
    /// better detail than noisy guides without `cleanAux`, at the cost of two more runs.
    pub fn prefilter_aux(
        &self,
        albedo: &LinearImage,
        normal: &LinearImage,
        run: &Run,
    ) -> Result<(LinearImage, LinearImage), DenoiseError> {
        if (albedo.width(), albedo.height()) != (normal.width(), normal.height()) {
            return Err(DenoiseError::SizeMismatch {
                what: "normal",
                color: (albedo.width(), albedo.height()),
                aux: (normal.width(), normal.height()),
            });
        }
        let albedo = sanitized_albedo(albedo, albedo)?;
        let normal = sanitized_normal(normal, normal)?;
        let run = Run {
            input_scale: None,
            ..run.clone()
        };
        let params = Params {
            hdr: false,
            clean_aux: false,
            run: &run,
        };
        let mut a = self.run(&[(c"albedo", &albedo)], &params)?;
        let mut n = self.run(&[(c"normal", &normal)], &params)?;
        for p in a.pixels_mut() {
            *p = p.map(|v| {
                if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            });
        }
        for p in n.pixels_mut() {
            *p = p.map(|v| {
                if v.is_finite() {
                    v.clamp(-1.0, 1.0)
                } else {
                    0.0
                }
            });
        }
        Ok((a, n))
    }

    /// One `RT` filter over `inputs` (all the same size, the first one's), into a new
    /// image; an image with a side under [`MIN_SIDE`] is mirrored out to it first, one
    /// with a side over [`MAX_SIDE`] denoised in overlapping strips.
    fn run(
        &self,
        inputs: &[(&CStr, &LinearImage)],
        params: &Params,
    ) -> Result<LinearImage, DenoiseError> {
        let (w, h) = (inputs[0].1.width(), inputs[0].1.height());
        if w > MAX_SIDE || h > MAX_SIDE {
            return self.run_in_strips(inputs, params);
        }
        if w == 0 || h == 0 || (w >= MIN_SIDE && h >= MIN_SIDE) {
            return self.run_exact(inputs, params);
        }
        let (pw, ph) = (w.max(MIN_SIDE), h.max(MIN_SIDE));
        let out = self.run_on(inputs, params, |image| {
            LinearImage::from_fn(pw, ph, |x, y| *image.get(mirror(x, w), mirror(y, h)))
        })?;
        Ok(LinearImage::from_fn(w, h, |x, y| *out.get(x, y)))
    }

    /// [`Self::run`] on strips across the longer side, each at most [`MAX_SIDE`] long
    /// with [`STRIP_OVERLAP`] pixels of context on either side, of which only the middle
    /// is kept: the network sees each kept pixel's neighbourhood as in one run.
    fn run_in_strips(
        &self,
        inputs: &[(&CStr, &LinearImage)],
        params: &Params,
    ) -> Result<LinearImage, DenoiseError> {
        let (w, h) = (inputs[0].1.width(), inputs[0].1.height());
        let across_x = w >= h;
        // A strip's pixel (along, across) is the image's (x, y) across x, (y, x) across y.
        let at = |along: u32, across: u32| {
            if across_x {
                (along, across)
            } else {
                (across, along)
            }
        };
        let (long, short) = at(w, h);
        let core = MAX_SIDE - 2 * STRIP_OVERLAP;
        let mut out = LinearImage::filled(w, h, Rgb::ZERO);
        for start in (0..long).step_by(core as usize) {
            let end = (start + core).min(long);
            let from = start.saturating_sub(STRIP_OVERLAP);
            let to = (end + STRIP_OVERLAP).min(long);
            let (sw, sh) = at(to - from, short);
            let done = self.run_on(inputs, params, |image| {
                LinearImage::from_fn(sw, sh, |x, y| {
                    let (along, across) = at(x, y);
                    let (ix, iy) = at(from + along, across);
                    *image.get(ix, iy)
                })
            })?;
            for along in start..end {
                for across in 0..short {
                    let (x, y) = at(along, across);
                    let (sx, sy) = at(along - from, across);
                    out.set(x, y, *done.get(sx, sy));
                }
            }
        }
        Ok(out)
    }

    /// [`Self::run`] on each input made into another image by `make` (all the same size).
    fn run_on(
        &self,
        inputs: &[(&CStr, &LinearImage)],
        params: &Params,
        make: impl Fn(&LinearImage) -> LinearImage,
    ) -> Result<LinearImage, DenoiseError> {
        let made: Vec<LinearImage> = inputs.iter().map(|(_, image)| make(image)).collect();
        let named: Vec<(&CStr, &LinearImage)> = inputs
            .iter()
            .zip(&made)
            .map(|((name, _), image)| (*name, image))
            .collect();
        self.run(&named, params)
    }

    /// One `RT` filter run at the inputs' own size. A filter per call: creating and
    /// committing one costs little next to executing it (measured, see benches/denoise.rs).
    fn run_exact(
        &self,
        inputs: &[(&CStr, &LinearImage)],
        params: &Params,
    ) -> Result<LinearImage, DenoiseError> {
        let (w, h) = (inputs[0].1.width(), inputs[0].1.height());
        let mut out = LinearImage::filled(w, h, Rgb::ZERO);
        if out.is_empty() {
            return Ok(out);
        }
        let cancel = &params.run.cancel;
        if cancel.is_cancelled() {
            return Err(DenoiseError::Cancelled);
        }
        let device = self.lock_device(cancel)?;
        let api = &self.api;
        let (wu, hu, stride) = (w as usize, h as usize, std::mem::size_of::<Rgb>());
        // SAFETY: the images outlive the filter (released by `Filter`'s drop before this
        // returns); OIDN only reads the inputs, and writes w×h FLOAT3 pixels to `out`.
        unsafe {
            let filter = Filter {
                api,
                handle: (api.new_filter)(device.0, c"RT".as_ptr()),
            };
            self.check(device.0, "creating the RT filter")?;
            if filter.handle.is_null() {
                return Err(DenoiseError::Library(
                    "creating the RT filter: no filter and no error".into(),
                ));
            }
            let set = |name: &CStr, ptr: *mut c_void| {
                (api.set_shared_filter_image)(
                    filter.handle,
                    name.as_ptr(),
                    ptr,
                    library::FORMAT_FLOAT3,
                    wu,
                    hu,
                    0,
                    stride,
                    stride * wu,
                );
            };
            for (name, image) in inputs {
                set(name, image.pixels().as_ptr().cast_mut().cast());
            }
            set(c"output", out.pixels_mut().as_mut_ptr().cast());
            (api.set_filter_bool)(filter.handle, c"hdr".as_ptr(), params.hdr);
            (api.set_filter_bool)(filter.handle, c"cleanAux".as_ptr(), params.clean_aux);
            (api.set_filter_int)(
                filter.handle,
                c"quality".as_ptr(),
                quality_code(params.run.quality),
            );
            if let Some(scale) = params.run.input_scale {
                (api.set_filter_float)(filter.handle, c"inputScale".as_ptr(), scale);
            }
            if let Some(mb) = params.run.max_memory_mb {
                let mb = i32::try_from(mb).unwrap_or(i32::MAX);
                (api.set_filter_int)(filter.handle, c"maxMemoryMB".as_ptr(), mb);
            }
            let token: *const CancelToken = cancel;
            (api.set_filter_progress_monitor)(
                filter.handle,
                Some(keep_going),
                token.cast_mut().cast(),
            );
            (api.commit_filter)(filter.handle);
            self.check(device.0, &format!("committing the RT filter ({w}x{h})"))?;
            (api.execute_filter)(filter.handle);
            self.check(device.0, &format!("denoising a {w}x{h} image"))?;
        }
        Ok(out)
    }

    /// The device, waited for while `cancel` has not fired: another job's denoise may
    /// hold it for seconds, and a cancelled job must not wait for it.
    fn lock_device(&self, cancel: &CancelToken) -> Result<MutexGuard<'_, Device>, DenoiseError> {
        loop {
            match self.device.try_lock() {
                Ok(device) => return Ok(device),
                Err(TryLockError::Poisoned(p)) => return Ok(p.into_inner()),
                Err(TryLockError::WouldBlock) => {
                    if cancel.is_cancelled() {
                        return Err(DenoiseError::Cancelled);
                    }
                    std::thread::sleep(std::time::Duration::from_millis(2));
                }
            }
        }
    }

    /// OIDN's pending error on this thread, if any, as `DenoiseError::Library`
    /// (`Cancelled` when our progress monitor aborted the filter).
    ///
    /// # Safety
    /// `device` is null or a live device handle of `self.api`.
    unsafe fn check(&self, device: DeviceHandle, during: &str) -> Result<(), DenoiseError> {
        let mut message: *const c_char = std::ptr::null();
        let code = (self.api.get_device_error)(device, &mut message);
        if code == library::ERROR_NONE {
            return Ok(());
        }
        if code == library::ERROR_CANCELLED {
            return Err(DenoiseError::Cancelled);
        }
        let text = if message.is_null() {
            String::from("no message")
        } else {
            CStr::from_ptr(message).to_string_lossy().into_owned()
        };
        Err(DenoiseError::Library(format!(
            "{during}: {text} ({})",
            error_name(code)
        )))
    }
}

impl Drop for Denoiser {
    fn drop(&mut self) {
        let device = self
            .device
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner);
        if !device.0.is_null() {
            // SAFETY: the handle came from `new_device` and is released once.
            unsafe { (self.api.release_device)(device.0) };
        }
    }
}

/// OIDN's progress monitor: go on while the run's token has not fired.
///
/// # Safety
/// `token` is the `CancelToken` `run_exact` passed, alive while the filter executes.
unsafe extern "C" fn keep_going(token: *mut c_void, _done: f64) -> bool {
    let cancel = &*token.cast::<CancelToken>().cast_const();
    !cancel.is_cancelled()
}

/// Releases a filter on every path out of `Denoiser::run`.
struct Filter<'a> {
    api: &'a Api,
    handle: FilterHandle,
}

impl Drop for Filter<'_> {
    fn drop(&mut self) {
        if !self.handle.is_null() {
            // SAFETY: the handle came from `new_filter` and is released once.
            unsafe { (self.api.release_filter)(self.handle) };
        }
    }
}

/// `albedo` with each channel in [0, 1] (NaN → 0), after checking it has `color`'s size.
fn sanitized_albedo(
    albedo: &LinearImage,
    color: &LinearImage,
) -> Result<LinearImage, DenoiseError> {
    same_size("albedo", albedo, color)?;
    Ok(albedo.map(|&c| c.map(|v| if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) })))
}

/// `normal` with each component in [-1, 1] (NaN → 0), after checking it has `color`'s size.
fn sanitized_normal(
    normal: &LinearImage,
    color: &LinearImage,
) -> Result<LinearImage, DenoiseError> {
    same_size("normal", normal, color)?;
    Ok(normal.map(|&c| c.map(|v| if v.is_nan() { 0.0 } else { v.clamp(-1.0, 1.0) })))
}

fn same_size(
    what: &'static str,
    aux: &LinearImage,
    color: &LinearImage,
) -> Result<(), DenoiseError> {
    let (a, c) = ((aux.width(), aux.height()), (color.width(), color.height()));
    if a == c {
        Ok(())
    } else {
        Err(DenoiseError::SizeMismatch {
            what,
            color: c,
            aux: a,
        })
    }
}

/// `i` reflected into `0..n` (period 2n: 0 1 .. n-1 n-1 .. 1 0 0 1 ..), for padding.
fn mirror(i: u32, n: u32) -> u32 {
    let i = i % (2 * n);
    if i < n {
        i
    } else {
        2 * n - 1 - i
    }
}

fn quality_code(q: Quality) -> i32 {
    match q {
        Quality::Fast => library::QUALITY_FAST,
        Quality::Balanced => library::QUALITY_BALANCED,
        Quality::High => library::QUALITY_HIGH,
    }
}

/// OIDN's `OIDNError` codes (oidn.h).
fn error_name(code: i32) -> &'static str {
    match code {
        1 => "unknown error",
        2 => "invalid argument",
        3 => "invalid operation",
        4 => "out of memory",
        5 => "unsupported hardware",
        6 => "cancelled",
        _ => "unrecognised error code",
    }
}

/// 20501 → "2.5.1" (OIDN's `version` = major·10000 + minor·100 + patch).
fn version_string(v: i32) -> String {
    format!("{}.{}.{}", v / 10000, v / 100 % 100, v % 100)
}
