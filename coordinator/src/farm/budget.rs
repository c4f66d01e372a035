//! What a job costs the coordinator's memory, known before anything of it is allocated:
//! `Job::prepare_within` hands it to an admission check between validating the scene and
//! allocating the framebuffer.

use tessera_film::aov::{AovLayers, Layout};
use tessera_film::Framebuffer;

/// A job's memory in the coordinator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Footprint {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Whether the framebuffer keeps even-sample sums (a noise target).
    pub even_sums: bool,
    /// The bundle held with the job (scene text and assets).
    pub bundle_bytes: u64,
    /// The AOV layers kept beside the framebuffer.
    pub aovs: Layout,
}

impl Footprint {
    /// The framebuffer's bytes (`Framebuffer::bytes_for`), with its AOV layers'
    /// (`AovLayers::bytes_for`).
    pub fn framebuffer_bytes(&self) -> u64 {
        Framebuffer::bytes_for(self.width, self.height, self.even_sums)
            + AovLayers::bytes_for(self.aovs, self.width, self.height)
    }

    /// Everything the job holds while it is kept: framebuffer and bundle.
    pub fn bytes(&self) -> u64 {
        self.framebuffer_bytes() + self.bundle_bytes
    }
}

/// An admission check: `Ok` lets the job be allocated, an error refuses it.
pub type Admit<'a> = &'a mut dyn FnMut(&Footprint) -> Result<(), super::SubmitError>;
