//! Tessera's wire contract: the gRPC service between coordinator, workers and clients,
//! generated from `proto/tessera.proto` at build time with no system `protoc`; the one
//! place where wire types meet domain types (`convert`); and the client side's connection
//! (`connect`: endpoints, errors, backoff) shared by the worker, the viewer and the CLI,
//! with the certificates, keys and tokens it uses (`credentials`).
//!
//! Only this crate and each crate's `service.rs`/`client.rs` touch the generated types.
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod connect;
pub mod convert;
pub mod credentials;
pub mod preview;

/// Version 1 of the protocol.
#[allow(missing_docs, clippy::large_enum_variant)]
pub mod v1 {
    tonic::include_proto!("tessera.v1");
}

pub use v1::*;

/// The encoded `FileDescriptorSet` of `tessera.proto` (with its comments), for server
/// reflection: generic gRPC tools list and call the services from it alone.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/tessera_descriptor.bin"));

/// The protocol version this build speaks.
pub const PROTOCOL_VERSION: v1::ProtocolVersion = v1::ProtocolVersion::Current;

/// The most batch results one `Results` message may carry. A worker sends more as several
/// messages; the coordinator refuses a message with more. It bounds the largest legal
/// worker message, and so the decode limit of the `Workers` service: a message of many
/// tiny entries inflates many times in memory when decoded, so the fewer bytes a message
/// may have, the less any message can cost.
pub const MAX_RESULTS_PER_MESSAGE: usize = 8;
