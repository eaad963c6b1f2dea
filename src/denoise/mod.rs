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
use std::sync::{Mutex, OnceLock, PoisonError};

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

/// OIDN's `quality` parameter: a streamed frame can take `Fast`, the final one `High`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    Fast,
    Balanced,
    High,
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
struct Params {
    hdr: bool,
    clean_aux: bool,
    quality: Quality,
    input_scale: Option<f32>,
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

    /// `color` denoised. `input_scale` multiplies the colour so that 1.0 means
    /// 100 cd/m² (OIDN's HDR convention); `None` lets OIDN pick it per image.
    ///
    /// With `aux`, albedo and normal guide the filter; `aux.clean` sets OIDN's `cleanAux`
    /// (only for noise-free images, else their noise survives: api.md). Non-finite or
    /// negative radiance becomes 0 and anything above [`MAX_RADIANCE`] is clamped to it
    /// first; the output is finite and non-negative.
    pub fn denoise(
        &self,
        color: &LinearImage,
        aux: Option<&Aux<'_>>,
        quality: Quality,
        input_scale: Option<f32>,
    ) -> Result<LinearImage, DenoiseError> {
        if let Some(s) = input_scale {
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
            quality,
            input_scale,
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
        quality: Quality,
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
        let params = Params {
            hdr: false,
            clean_aux: false,
            quality,
            input_scale: None,
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
    /// image; an image with a side under [`MIN_SIDE`] is mirrored out to it first.
    fn run(
        &self,
        inputs: &[(&CStr, &LinearImage)],
        params: &Params,
    ) -> Result<LinearImage, DenoiseError> {
        let (w, h) = (inputs[0].1.width(), inputs[0].1.height());
        if w == 0 || h == 0 || (w >= MIN_SIDE && h >= MIN_SIDE) {
            return self.run_exact(inputs, params);
        }
        let (pw, ph) = (w.max(MIN_SIDE), h.max(MIN_SIDE));
        let padded: Vec<LinearImage> = inputs
            .iter()
            .map(|(_, image)| {
                LinearImage::from_fn(pw, ph, |x, y| *image.get(mirror(x, w), mirror(y, h)))
            })
            .collect();
        let named: Vec<(&CStr, &LinearImage)> = inputs
            .iter()
            .zip(&padded)
            .map(|((name, _), image)| (*name, image))
            .collect();
        let out = self.run_exact(&named, params)?;
        Ok(LinearImage::from_fn(w, h, |x, y| *out.get(x, y)))
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
        let device = self.device.lock().unwrap_or_else(PoisonError::into_inner);
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
                quality_code(params.quality),
            );
            if let Some(scale) = params.input_scale {
                (api.set_filter_float)(filter.handle, c"inputScale".as_ptr(), scale);
            }
            (api.commit_filter)(filter.handle);
            self.check(device.0, &format!("committing the RT filter ({w}x{h})"))?;
            (api.execute_filter)(filter.handle);
            self.check(device.0, &format!("denoising a {w}x{h} image"))?;
        }
        Ok(out)
    }

    /// OIDN's pending error on this thread, if any, as `DenoiseError::Library`.
    ///
    /// # Safety
    /// `device` is null or a live device handle of `self.api`.
    unsafe fn check(&self, device: DeviceHandle, during: &str) -> Result<(), DenoiseError> {
        let mut message: *const c_char = std::ptr::null();
        let code = (self.api.get_device_error)(device, &mut message);
        if code == library::ERROR_NONE {
            return Ok(());
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
