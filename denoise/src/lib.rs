//! Intel Open Image Denoise (OIDN) on a finished image, guided by its albedo and normal
//! AOV layers.
//!
//! The library is loaded at run time (libloading) rather than linked at build time (the
//! `oidn` crate's way): building Tessera then needs no OIDN, a machine without it renders
//! as before, and only `--denoise` needs `libOpenImageDenoise` — from a path given by
//! `--oidn-lib`/`TESSERA_OIDN`, or the one PyPI's `pyoidn` wheel ships. The C API used is
//! the few calls of OIDN's ray-tracing filter with shared images, stable from OIDN 1.x to
//! 2.x. This is the crate's only unsafe code: each call's contract is stated beside it.

use std::ffi::{c_char, c_void, CStr, CString};
use std::path::{Path, PathBuf};

/// Why denoising could not run.
#[derive(Debug, thiserror::Error)]
pub enum DenoiseError {
    /// The library could not be loaded.
    #[error("cannot load Open Image Denoise from {path}: {source}")]
    Load {
        /// The path tried.
        path: PathBuf,
        /// The loader's reason.
        source: libloading::Error,
    },
    /// OIDN reported an error.
    #[error("Open Image Denoise failed: {0}")]
    Oidn(String),
    /// The buffers do not fit the size.
    #[error("denoising a {width}x{height} image needs {expected} floats per buffer, got {got}")]
    Size {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// 3 × pixels.
        expected: usize,
        /// What came.
        got: usize,
    },
}

type Device = *mut c_void;
type Filter = *mut c_void;

/// OIDN_DEVICE_TYPE_DEFAULT.
const DEVICE_DEFAULT: i32 = 0;
/// OIDN_FORMAT_FLOAT3.
const FORMAT_FLOAT3: i32 = 3;
/// OIDN_ERROR_NONE.
const ERROR_NONE: i32 = 0;

/// The library's entry points, resolved once.
struct Api {
    new_device: unsafe extern "C" fn(i32) -> Device,
    commit_device: unsafe extern "C" fn(Device),
    release_device: unsafe extern "C" fn(Device),
    get_device_error: unsafe extern "C" fn(Device, *mut *const c_char) -> i32,
    new_filter: unsafe extern "C" fn(Device, *const c_char) -> Filter,
    set_shared_filter_image:
        unsafe extern "C" fn(Filter, *const c_char, *mut c_void, i32, usize, usize, usize, usize, usize),
    set_filter_bool: unsafe extern "C" fn(Filter, *const c_char, bool),
    commit_filter: unsafe extern "C" fn(Filter),
    execute_filter: unsafe extern "C" fn(Filter),
    release_filter: unsafe extern "C" fn(Filter),
    _lib: libloading::Library,
}

impl Api {
    fn load(path: &Path) -> Result<Api, DenoiseError> {
        let err = |source| DenoiseError::Load { path: path.to_owned(), source };
        // SAFETY: loading runs the library's initialisers; OIDN's are its own static setup.
        let lib = unsafe { libloading::Library::new(path) }.map_err(err)?;
        // SAFETY: each symbol is given the signature of OIDN's C API (oidn.h) for that name.
        unsafe {
            Ok(Api {
                new_device: *lib.get(b"oidnNewDevice\0").map_err(err)?,
                commit_device: *lib.get(b"oidnCommitDevice\0").map_err(err)?,
                release_device: *lib.get(b"oidnReleaseDevice\0").map_err(err)?,
                get_device_error: *lib.get(b"oidnGetDeviceError\0").map_err(err)?,
                new_filter: *lib.get(b"oidnNewFilter\0").map_err(err)?,
                set_shared_filter_image: *lib.get(b"oidnSetSharedFilterImage\0").map_err(err)?,
                set_filter_bool: *lib.get(b"oidnSetFilterBool\0").map_err(err)?,
                commit_filter: *lib.get(b"oidnCommitFilter\0").map_err(err)?,
                execute_filter: *lib.get(b"oidnExecuteFilter\0").map_err(err)?,
                release_filter: *lib.get(b"oidnReleaseFilter\0").map_err(err)?,
                _lib: lib,
            })
        }
    }

    /// The device's pending error, if any.
    fn error(&self, device: Device) -> Option<String> {
        let mut message: *const c_char = std::ptr::null();
        // SAFETY: `device` is live; OIDN sets `message` to a string it owns or leaves it null.
        let code = unsafe { (self.get_device_error)(device, &mut message) };
        (code != ERROR_NONE).then(|| {
            if message.is_null() {
                format!("error code {code}")
            } else {
                // SAFETY: a NUL-terminated string valid until the next call on the device.
                unsafe { CStr::from_ptr(message) }.to_string_lossy().into_owned()
            }
        })
    }
}

/// The library file names tried in a directory, newest API first.
const NAMES: [&str; 3] = ["libOpenImageDenoise.so.2", "libOpenImageDenoise.so", "libOpenImageDenoise.so.1"];

/// The library in `dir` (searched below it too: a wheel keeps it a level or two down).
pub fn find_in(dir: &Path) -> Option<PathBuf> {
    let mut stack = vec![(dir.to_owned(), 0)];
    while let Some((d, depth)) = stack.pop() {
        for name in NAMES {
            let p = d.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
        if depth < 6 {
            for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
                if e.file_type().is_ok_and(|t| t.is_dir()) {
                    stack.push((e.path(), depth + 1));
                }
            }
        }
    }
    None
}

/// Denoises `color` (linear RGB, 3 floats a pixel, top row first) in place, guided by
/// `albedo` and `normal` (the same layout), with OIDN's ray-tracing filter for HDR input,
/// the library at `lib`.
pub fn denoise(
    lib: &Path,
    width: u32,
    height: u32,
    color: &mut [f32],
    albedo: &[f32],
    normal: &[f32],
) -> Result<(), DenoiseError> {
    let expected = width as usize * height as usize * 3;
    for got in [color.len(), albedo.len(), normal.len()] {
        if got != expected {
            return Err(DenoiseError::Size { width, height, expected, got });
        }
    }
    let api = Api::load(lib)?;
    let input = color.to_vec();
    let (w, h) = (width as usize, height as usize);
    let name = |s: &str| CString::new(s).expect("no NUL");
    // SAFETY: the device and filter are used only here and released before returning; the
    // shared images point into buffers that outlive the filter's execution (OIDN only
    // reads the inputs and writes `color`), each w × h FLOAT3 pixels, packed (strides 0
    // mean packed).
    unsafe {
        let device = (api.new_device)(DEVICE_DEFAULT);
        if device.is_null() {
            return Err(DenoiseError::Oidn("no device could be created".into()));
        }
        (api.commit_device)(device);
        if let Some(e) = api.error(device) {
            (api.release_device)(device);
            return Err(DenoiseError::Oidn(e));
        }
        let filter = (api.new_filter)(device, name("RT").as_ptr());
        let image = |slot: &str, ptr: *const f32| {
            (api.set_shared_filter_image)(
                filter,
                name(slot).as_ptr(),
                ptr as *mut c_void,
                FORMAT_FLOAT3,
                w,
                h,
                0,
                0,
                0,
            )
        };
        image("color", input.as_ptr());
        image("albedo", albedo.as_ptr());
        image("normal", normal.as_ptr());
        image("output", color.as_mut_ptr());
        (api.set_filter_bool)(filter, name("hdr").as_ptr(), true);
        (api.commit_filter)(filter);
        let mut failure = api.error(device);
        if failure.is_none() {
            (api.execute_filter)(filter);
            failure = api.error(device);
        }
        (api.release_filter)(filter);
        (api.release_device)(device);
        match failure {
            Some(e) => Err(DenoiseError::Oidn(e)),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_library_is_a_clear_error() {
        let mut c = vec![0.0; 3];
        let e =
            denoise(Path::new("/nonexistent/libOpenImageDenoise.so.2"), 1, 1, &mut c, &[0.0; 3], &[0.0; 3])
                .unwrap_err()
                .to_string();
        assert!(
            e.starts_with("cannot load Open Image Denoise from /nonexistent/libOpenImageDenoise.so.2"),
            "{e}"
        );
        let e = denoise(Path::new("x"), 2, 1, &mut c, &[0.0; 3], &[0.0; 3]).unwrap_err().to_string();
        assert!(e.contains("needs 6 floats per buffer, got 3"), "{e}");
        assert_eq!(find_in(Path::new("/nonexistent")), None);
    }
}
