//! Tessera's viewer: keeps a replica of a job's framebuffer from the coordinator's watch
//! stream (`state.rs`) and shows it: in a desktop window (`window.rs`), or as headless
//! snapshots written to files (`headless.rs`).
//! The network code (`conn.rs`) never draws and the drawing code never touches the network.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod conn;
pub mod headless;
pub mod state;
pub mod tev;
pub mod window;
