//! What the coordinator's listener accepts: the largest legal worker message (the decode
//! limit of the `Workers` service, computed here from the constants that bound it) and the
//! HTTP/2 settings of every connection.

use std::time::Duration;

use tessera_description::limits::MAX_NAME_BYTES;
use tonic::transport::Server;

use crate::scheduler::rounds::TILE;
use crate::scheduler::{PASS_ONE_MAX, PASS_TWO_MAX_PIXELS};

/// The longest lease token a worker may echo back (`Batch.lease`); the coordinator's own
/// tokens are shorter.
pub const MAX_LEASE_TOKEN_BYTES: usize = 64;

/// The longest error a worker may report for a batch (`BatchFailed.error`).
pub const MAX_WORKER_ERROR_BYTES: usize = 4096;

/// The most scenes a worker may say it holds (`Hello.held_scenes`): a worker preloads one;
/// the bound keeps what the coordinator stores per worker small.
pub const MAX_HELD_SCENES: usize = 16;

/// Whether `hash` is a scene's content hash as `Bundle::hash` writes it: blake3 in 64
/// lower-case hex digits. Held scenes are matched against job hashes as strings, so
/// anything else could never match and is refused as a malformed Hello.
pub fn is_scene_hash(hash: &str) -> bool {
    hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// The most pixels any batch has: pass one's largest, pass two's largest, or a round's
/// tile.
const MAX_BATCH_PIXELS: usize = max(max(PASS_ONE_MAX, PASS_TWO_MAX_PIXELS), (TILE * TILE) as usize);

/// A varint's longest encoding (a `u64`), and a length prefix's for any length we allow.
const VARINT: usize = 10;
const LEN: usize = 5;
/// A field's tag (field numbers below 16).
const TAG: usize = 1;
/// A field's tag (field numbers 16 to 2047).
const TAG2: usize = 2;
/// The most AOV sums a pixel returns (albedo 3, normal 3, depth 2).
const AOV_PER_PIXEL: usize = 8;

/// The largest legal encoded `BatchResult`: every id, count and sum at its longest varint.
const MAX_RESULT_BYTES: usize = 3 * (TAG + VARINT)   // job_id, batch_id, attempt
    + TAG + LEN + 3 * MAX_BATCH_PIXELS * VARINT      // sums
    + 2 * (TAG + VARINT)                             // nonfinite_samples, render_micros
    + TAG + LEN + MAX_BATCH_PIXELS * VARINT          // even_sums
    + TAG + LEN + MAX_LEASE_TOKEN_BYTES              // lease
    + TAG2 + LEN + AOV_PER_PIXEL * MAX_BATCH_PIXELS * VARINT; // aov_sums

/// The largest legal `WorkerMessage`: a `Results` returning `MAX_RESULTS_PER_MESSAGE` of
/// the largest batches at once (a `Hello` or a `BatchFailed` is far smaller). The
/// `Workers` service decodes nothing larger, so a worker cannot make the coordinator buffer
/// and inflate a bundle's worth of packed varints (~2.6 MB here against 257 MiB for
/// `Coordinator`).
pub const MAX_WORKER_MESSAGE_BYTES: usize = TAG + LEN // WorkerMessage.results
    + tessera_proto::MAX_RESULTS_PER_MESSAGE * (TAG + LEN + MAX_RESULT_BYTES)
    + TAG + VARINT; // credit

// A `Hello` or `BatchFailed` at its limits fits; a bundle does not, by far.
const _: () = assert!(
    MAX_WORKER_MESSAGE_BYTES > MAX_NAME_BYTES * 2 + MAX_HELD_SCENES * (64 + 2) + MAX_WORKER_ERROR_BYTES
);
const _: () = assert!(MAX_WORKER_MESSAGE_BYTES < super::MAX_MESSAGE_BYTES / 2);

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Concurrent streams one HTTP/2 connection may open. A worker needs one, a viewer one, the
/// CLI a few; more are queued by the client's HTTP/2 layer, not refused.
pub const MAX_STREAMS_PER_CONNECTION: u32 = 100;

/// Keep-alive pings on every connection, so that a peer that went away without closing
/// (its memory held in buffers and streams) is dropped.
pub const KEEPALIVE_INTERVAL: Duration = Duration::from_secs(20);
/// How long a keep-alive ping may go unanswered.
pub const KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(10);

/// The longest a request may take to be answered (for a stream: until its first message):
/// a client that opens a call and then sends nothing holds its buffers this long at most.
/// Long enough for a full bundle on a slow link (256 MiB at 1 MB/s).
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(300);

/// The largest header list a client may send (gRPC metadata: a few tokens).
const MAX_HEADER_LIST_BYTES: u32 = 16 << 10;

/// Applies the connection limits above to a server builder.
pub(super) fn configure(server: Server) -> Server {
    server
        .max_concurrent_streams(MAX_STREAMS_PER_CONNECTION)
        .http2_keepalive_interval(Some(KEEPALIVE_INTERVAL))
        .http2_keepalive_timeout(Some(KEEPALIVE_TIMEOUT))
        .http2_max_header_list_size(MAX_HEADER_LIST_BYTES)
        .http2_max_pending_accept_reset_streams(Some(64))
        .timeout(REQUEST_TIMEOUT)
        .tcp_keepalive(Some(KEEPALIVE_INTERVAL))
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;
    use tessera_proto::v1 as pb;

    fn largest_result() -> pb::BatchResult {
        pb::BatchResult {
            job_id: u64::MAX,
            batch_id: u64::MAX,
            attempt: u32::MAX,
            sums: vec![u64::MAX; 3 * MAX_BATCH_PIXELS],
            nonfinite_samples: u64::MAX,
            render_micros: u64::MAX,
            even_sums: vec![u64::MAX; MAX_BATCH_PIXELS],
            lease: vec![0xff; MAX_LEASE_TOKEN_BYTES],
            aov_sums: vec![u64::MAX; AOV_PER_PIXEL * MAX_BATCH_PIXELS],
        }
    }

    #[test]
    fn the_worker_limit_is_just_above_the_largest_legal_worker_message() {
        let results = pb::Results {
            results: vec![largest_result(); tessera_proto::MAX_RESULTS_PER_MESSAGE],
            credit: u32::MAX,
        };
        let largest = pb::WorkerMessage { msg: Some(pb::worker_message::Msg::Results(results)) };
        let len = largest.encoded_len();
        assert!(len <= MAX_WORKER_MESSAGE_BYTES, "{len} > {MAX_WORKER_MESSAGE_BYTES}");
        // Just above: within 1 % (the length prefixes are counted at their longest).
        assert!(MAX_WORKER_MESSAGE_BYTES - len < len / 100, "{len} vs {MAX_WORKER_MESSAGE_BYTES}");
    }

    #[test]
    fn hello_and_failures_at_their_limits_fit() {
        let hello = pb::WorkerMessage {
            msg: Some(pb::worker_message::Msg::Hello(pb::Hello {
                protocol_version: 3,
                renderer_version: "x".repeat(MAX_NAME_BYTES),
                name: "x".repeat(MAX_NAME_BYTES),
                threads: u32::MAX,
                credit: u32::MAX,
                frames: true,
                held_scenes: vec!["f".repeat(64); MAX_HELD_SCENES],
            })),
        };
        let failed = pb::WorkerMessage {
            msg: Some(pb::worker_message::Msg::Failed(pb::BatchFailed {
                job_id: u64::MAX,
                batch_id: u64::MAX,
                attempt: u32::MAX,
                error: "x".repeat(MAX_WORKER_ERROR_BYTES),
                credit: u32::MAX,
                lease: vec![0; MAX_LEASE_TOKEN_BYTES],
                scene_refused: true,
            })),
        };
        assert!(hello.encoded_len() < MAX_WORKER_MESSAGE_BYTES);
        assert!(failed.encoded_len() < MAX_WORKER_MESSAGE_BYTES);
    }
}
