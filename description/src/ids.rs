//! Newtype ids, so that a job id is never passed where a batch id is meant.

use std::fmt;

macro_rules! id {
    ($(#[$doc:meta])* $name:ident, $prefix:literal) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name(pub u64);

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, concat!($prefix, "{}"), self.0)
            }
        }
    };
}

id!(
    /// A job, numbered from 1 in submission order.
    JobId,
    "job "
);
id!(
    /// A batch within its job, numbered from 0 in the walk's order.
    BatchId,
    "batch "
);
id!(
    /// A worker connection, numbered from 1.
    WorkerId,
    "worker "
);
