//! Why a batch cannot be rendered here, as the scene cache and the preload report it.

use crate::build::LoadError;

/// Why a batch cannot be rendered here: the message, and whether it is because the worker
/// refuses the job's scene altogether (then every batch of that job is refused alike).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Failure {
    pub(super) message: String,
    pub(super) scene_refused: bool,
}

impl Failure {
    pub(super) fn new(message: impl Into<String>) -> Failure {
        Failure { message: message.into(), scene_refused: false }
    }
}

impl From<LoadError> for Failure {
    fn from(e: LoadError) -> Failure {
        let scene_refused = matches!(e, LoadError::TooLarge { .. });
        Failure { message: e.to_string(), scene_refused }
    }
}
