//! How the CLI's gRPC clients report a coordinator's refusal: its status's message as an
//! error. Shared by `remote`'s commands and `layers`' fetch, it sits below both so that
//! neither depends on the other for it.

use anyhow::anyhow;

pub(crate) fn status_error(s: tonic::Status) -> anyhow::Error {
    anyhow!("{}", s.message())
}
