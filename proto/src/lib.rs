//! Tessera's wire contract: the gRPC service between coordinator, workers and clients,
//! generated from `proto/tessera.proto` at build time with no system `protoc`.
//!
//! Only this crate and each crate's `service.rs`/`client.rs` touch these types.
#![allow(missing_docs, clippy::large_enum_variant)]

/// Version 1 of the protocol.
pub mod v1 {
    tonic::include_proto!("tessera.v1");
}

pub use v1::*;

/// The protocol version this build speaks.
pub const PROTOCOL_VERSION: v1::ProtocolVersion = v1::ProtocolVersion::Current;
