//! `--aov`: the AOV layers a render, a submission or a fetch writes beside the image, in
//! one multi-layer OpenEXR file (`tessera_film::exr_layers`).

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use tessera_description::ids::JobId;
use tessera_description::job::Aovs;
use tessera_film::aov::Resolved;
use tessera_proto::connect::Client;
use tessera_proto::v1 as pb;

/// The `--aov` flag, shared by `render`, `submit` and `fetch`.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct AovArgs {
    /// AOV layers to write beside the image, comma-separated: albedo, normal, depth (first
    /// hit; the output must be .exr: one multi-layer OpenEXR file, see docs/aov.md).
    #[arg(long, value_name = "LAYERS", value_parser = parse_aovs)]
    pub aov: Option<Aovs>,
    /// Denoise the finished image once with Intel Open Image Denoise, guided by the albedo
    /// and normal layers (accumulated for it, written only if --aov names them).
    #[arg(long)]
    pub denoise: bool,
    /// The libOpenImageDenoise for --denoise, a file or a directory holding it [default:
    /// the pyoidn wheel's, in the project's venv target/python/oidn].
    #[arg(long, value_name = "PATH", env = "TESSERA_OIDN")]
    pub oidn_lib: Option<PathBuf>,
}

impl AovArgs {
    /// The layers to accumulate: those `--aov` names, and albedo and normal for `--denoise`.
    pub fn aovs(&self) -> Aovs {
        let mut a = self.written();
        a.albedo |= self.denoise;
        a.normal |= self.denoise;
        a
    }

    /// The layers to write (none without `--aov`).
    pub fn written(&self) -> Aovs {
        self.aov.unwrap_or_default()
    }

    /// The Open Image Denoise library `--denoise` loads: `--oidn-lib`/`TESSERA_OIDN` (a
    /// file, or a directory searched), else the pyoidn wheel in the project's venv
    /// (`scripts/python-venv.sh oidn tests/tools/oidn-requirements.txt`, beside this
    /// executable's target directory).
    pub fn oidn_library(&self) -> Result<PathBuf> {
        if let Some(p) = &self.oidn_lib {
            if p.is_file() {
                return Ok(p.clone());
            }
            return tessera_denoise::find_in(p).ok_or_else(|| {
                anyhow!("--denoise: no libOpenImageDenoise at {} (--oidn-lib / TESSERA_OIDN)", p.display())
            });
        }
        let venv = std::env::current_exe()
            .ok()
            .and_then(|exe| exe.parent()?.parent().map(|t| t.join("python/oidn/lib")));
        venv.as_deref().and_then(tessera_denoise::find_in).ok_or_else(|| {
            anyhow!(
                "--denoise: Open Image Denoise not found: give --oidn-lib PATH (or TESSERA_OIDN), or install the pyoidn wheel with scripts/python-venv.sh oidn tests/tools/oidn-requirements.txt"
            )
        })
    }

    /// Refuses `--aov` with an output that is not OpenEXR, and `--denoise` without its
    /// library, before anything is done.
    pub fn check(&self, output: Option<&Path>) -> Result<()> {
        if self.denoise {
            self.oidn_library()?;
            if output.is_none() {
                bail!("--denoise needs an output image (-o FILE) to write the denoised image to");
            }
        }
        if self.written() == Aovs::default() {
            return Ok(());
        }
        match output {
            Some(out) => tessera_film::exr_layers::check_path(out).map_err(|e| anyhow!("--aov: {e}")),
            None => bail!("--aov needs an output image (-o FILE.exr) to write the layers to"),
        }
    }
}

/// Parses `albedo,normal,depth` (any non-empty subset, any order).
pub fn parse_aovs(s: &str) -> Result<Aovs, String> {
    let mut a = Aovs::default();
    for name in s.split(',').map(str::trim) {
        match name {
            "albedo" => a.albedo = true,
            "normal" => a.normal = true,
            "depth" => a.depth = true,
            _ => {
                return Err(format!(
                    "unknown AOV layer {name:?}: expected albedo, normal or depth, comma-separated"
                ))
            }
        }
    }
    Ok(a)
}

/// Only the layers of `want` (the others emptied): what is written.
pub fn select(mut layers: Resolved, want: Aovs) -> Resolved {
    if !want.albedo {
        layers.albedo.clear();
    }
    if !want.normal {
        layers.normal.clear();
    }
    if !want.depth {
        layers.depth.clear();
    }
    layers
}

/// Writes the image (denoised first with `--denoise`), with the layers `--aov` names when
/// there are any (an OpenEXR file), or as before without.
pub fn write(
    out: &Path,
    width: u32,
    height: u32,
    rgb: &[f32],
    layers: Resolved,
    args: &AovArgs,
) -> Result<()> {
    let want = args.written();
    let denoised;
    let rgb = if args.denoise {
        if layers.albedo.is_empty() || layers.normal.is_empty() {
            bail!("--denoise: the job keeps no albedo and normal layers (submit it with --denoise or --aov albedo,normal)");
        }
        let lib = args.oidn_library()?;
        let mut color = rgb.to_vec();
        tessera_denoise::denoise(&lib, width, height, &mut color, &layers.albedo, &layers.normal)
            .map_err(|e| anyhow!("--denoise: {e}"))?;
        denoised = color;
        &denoised[..]
    } else {
        rgb
    };
    if want == Aovs::default() {
        tessera_film::output::write_image(out, width, height, rgb)?;
        return Ok(());
    }
    let missing: Vec<&str> = [
        (want.albedo && layers.albedo.is_empty(), "albedo"),
        (want.normal && layers.normal.is_empty(), "normal"),
        (want.depth && layers.depth.is_empty(), "depth"),
    ]
    .into_iter()
    .filter_map(|(m, name)| m.then_some(name))
    .collect();
    if !missing.is_empty() {
        bail!("the job keeps no {} layer (submit it with --aov to have it)", missing.join(", "));
    }
    tessera_film::exr_layers::write_layers(out, width, height, rgb, &select(layers, want))?;
    Ok(())
}

/// A job's image and its AOV layers from a coordinator (`FetchImage` with `aovs`).
pub async fn fetch(
    client: &mut Client,
    job: JobId,
    frame: Option<u32>,
    args: &AovArgs,
) -> Result<(u32, u32, Vec<f32>, Resolved)> {
    // The layers travel only when something is written or denoised with them.
    let aovs = args.denoise || args.written() != Aovs::default();
    let request = pb::FetchImageRequest { job_id: job.0, aovs, frame };
    let mut stream = client.fetch_image(request).await.map_err(crate::rpc::status_error)?.into_inner();
    let mut size = None;
    let (mut rgb, mut layers) = (Vec::new(), Resolved::default());
    let floats = |b: &[u8], into: &mut Vec<f32>| -> Result<()> {
        if !b.len().is_multiple_of(4) {
            bail!("the coordinator sent a layer chunk of {} bytes, not whole floats", b.len());
        }
        into.extend(b.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])));
        Ok(())
    };
    while let Some(chunk) = stream.message().await.map_err(crate::rpc::status_error)? {
        let (w, h) = *size.get_or_insert((chunk.width, chunk.height));
        if (chunk.width, chunk.height) != (w, h) {
            bail!("the coordinator sent an inconsistent image chunk");
        }
        if u64::from(chunk.row_start) * u64::from(w) * 3 != (rgb.len() as u64) {
            bail!("the coordinator sent image rows out of order");
        }
        floats(&chunk.rgb, &mut rgb)?;
        floats(&chunk.albedo, &mut layers.albedo)?;
        floats(&chunk.normal, &mut layers.normal)?;
        floats(&chunk.depth, &mut layers.depth)?;
    }
    let (w, h) = size.ok_or_else(|| anyhow!("the coordinator sent no image"))?;
    let n = w as usize * h as usize;
    for (name, got, per) in [
        ("RGB", rgb.len(), 3),
        ("albedo", layers.albedo.len(), 3),
        ("normal", layers.normal.len(), 3),
        ("depth", layers.depth.len(), 1),
    ] {
        if got != n * per && !(name != "RGB" && got == 0) {
            bail!("the coordinator sent {got} {name} values for a {w}x{h} image");
        }
    }
    Ok((w, h, rgb, layers))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_layer_lists_and_refuses_unknown_names() {
        assert_eq!(parse_aovs("albedo,normal,depth"), Ok(Aovs { albedo: true, normal: true, depth: true }));
        assert_eq!(parse_aovs("depth"), Ok(Aovs { depth: true, ..Aovs::default() }));
        assert!(parse_aovs("albedo,z").unwrap_err().contains("unknown AOV layer \"z\""));
    }

    #[test]
    fn png_outputs_are_refused() {
        let args = AovArgs { aov: Some(Aovs { albedo: true, ..Aovs::default() }), ..AovArgs::default() };
        let e = args.check(Some(Path::new("out.png"))).unwrap_err().to_string();
        assert!(e.contains("need an OpenEXR output (.exr), not PNG"), "{e}");
        assert!(args.check(Some(Path::new("out.exr"))).is_ok());
        assert!(AovArgs::default().check(Some(Path::new("out.png"))).is_ok());
    }
}
