//! Tessera's viewer: keeps a replica of a job's framebuffer from the coordinator's watch
//! stream and shows it (a window, or headless snapshots). Not built yet: issue 4.
#![forbid(unsafe_code)]
