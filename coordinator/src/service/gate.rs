//! A gate in front of `Submit`. tonic buffers a request's whole message, and prost then
//! copies its bytes out, before the handler sees it; so the gate stands before tonic's own
//! service and, for each submission:
//!
//! - waits for a turn: at most `budget::SUBMITS_AT_ONCE` are decoded and validated at once;
//! - reads the gRPC length prefix (the first 5 bytes of the body, nothing more) and reserves
//!   what decoding and validating that message can take from the memory budget
//!   ([`transient_bytes`]), refusing with `RESOURCE_EXHAUSTED` before a byte more is read
//!   when it does not fit; the reservation is held until the call ends.
//!
//! - reads the whole message (as tonic would) and counts its assets over the wire bytes
//!   (`scan.rs`), refusing more than `MAX_ASSETS` before prost allocates one per asset.
//!
//! So jobs and the submissions in flight together stay within the budget. Every other
//! call of the service has its request refused beyond `MAX_REQUEST_BYTES` from the same
//! prefix, instead of being buffered up to Submit's limit.

use std::collections::VecDeque;
use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use bytes::{Buf, Bytes};
use http_body::Frame;
use http_body_util::BodyExt;
use tessera_description::limits::{MAX_ASSETS, MAX_SCENE_BYTES};
use tokio::sync::Semaphore;
use tonic::body::Body;
use tonic::codegen::http::{Request, Response};
use tonic::codegen::{BoxFuture, Service};
use tonic::server::NamedService;
use tonic::Status;

use super::budget::MemoryBudget;
use super::scan;

/// The path of the one gated method.
const SUBMIT: &str = "/tessera.v1.Coordinator/Submit";

/// The largest request of any other `Coordinator` call (each is a few ids and flags).
pub(super) const MAX_REQUEST_BYTES: usize = 64 << 10;

/// What decoding and validating a submission of `message` bytes can take: tonic's buffer
/// and prost's copy of it, and the TOML parser's ~7 bytes per byte of scene text.
pub(super) fn transient_bytes(message: u64) -> u64 {
    2 * message + 7 * message.min(MAX_SCENE_BYTES)
}

/// A submission admitted outside gRPC (the web API's uploads): its turn among
/// `SUBMITS_AT_ONCE` and its memory reservation, held until it is dropped.
#[derive(Debug)]
pub struct Admission {
    _permit: tokio::sync::OwnedSemaphorePermit,
    _reservation: super::budget::Reservation,
}

impl super::CoordinatorService {
    /// Admits a submission of `bytes` (its whole upload) from `who` as the gate admits a
    /// gRPC Submit: Submit's role first (`PERMISSION_DENIED`), then a turn, then a
    /// reservation of what holding and validating it can take (`RESOURCE_EXHAUSTED` when
    /// it does not fit). Ask it before reading the upload; hold it until Submit returns.
    pub async fn admit_submission(
        &self,
        who: &super::auth::Principal,
        bytes: u64,
    ) -> Result<Admission, Status> {
        super::auth::require_of(Some(who), super::auth::Action::Submit)?;
        let permit = self.submits.clone().acquire_owned().await.expect("the permits are never closed");
        let reservation = self
            .budget
            .admit_submission(bytes, transient_bytes(bytes))
            .map_err(|e| Status::resource_exhausted(e.to_string()))?;
        Ok(Admission { _permit: permit, _reservation: reservation })
    }
}

/// `inner` with its `Submit` calls admitted as above.
#[derive(Clone)]
pub(super) struct SubmitGate<S> {
    inner: S,
    permits: Arc<Semaphore>,
    budget: MemoryBudget,
}

impl<S> SubmitGate<S> {
    pub(super) fn new(inner: S, permits: Arc<Semaphore>, budget: MemoryBudget) -> Self {
        SubmitGate { inner, permits, budget }
    }
}

impl<S: NamedService> NamedService for SubmitGate<S> {
    const NAME: &'static str = S::NAME;
}

impl<S> Service<Request<Body>> for SubmitGate<S>
where
    S: Service<Request<Body>, Response = Response<Body>, Error = Infallible> + Clone + Send + 'static,
    S::Future: Send + 'static,
{
    type Response = Response<Body>;
    type Error = Infallible;
    type Future = BoxFuture<Self::Response, Self::Error>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: Request<Body>) -> Self::Future {
        // The clone that was made ready serves this call (tower's rule for cloned services).
        let clone = self.inner.clone();
        let mut inner = std::mem::replace(&mut self.inner, clone);
        let submit = request.uri().path() == SUBMIT;
        if submit {
            // The role before anything else: a worker's or viewer's token must not hold a
            // permit, reserve budget or have its body decoded (the interceptor, which stands
            // before the gate, only said who is calling).
            let who = request.extensions().get::<super::auth::Principal>();
            if let Err(refused) = super::auth::require_of(who, super::auth::Action::Submit) {
                return Box::pin(async move { Ok(refused.into_http::<Body>()) });
            }
        }
        let (permits, budget) = (self.permits.clone(), self.budget.clone());
        Box::pin(async move {
            // Never closed, so acquiring only waits.
            let _permit = if submit { Some(permits.acquire_owned().await) } else { None };
            let (parts, mut body) = request.into_parts();
            let mut read = VecDeque::new();
            let mut have = 0usize;
            let mut prefix = Vec::with_capacity(5);
            while prefix.len() < 5 {
                match body.frame().await {
                    Some(Ok(frame)) => {
                        if let Some(data) = frame.data_ref() {
                            let take = (5 - prefix.len()).min(data.len());
                            prefix.extend_from_slice(&data.chunk()[..take]);
                            have += data.len();
                        }
                        read.push_back(frame);
                    }
                    // The body ended or broke: tonic reports it as it would have.
                    _ => break,
                }
            }
            let len = (prefix.len() == 5)
                .then(|| u64::from(u32::from_be_bytes([prefix[1], prefix[2], prefix[3], prefix[4]])));
            if !submit {
                // Every other call's request is a few ids and flags: tonic would buffer up
                // to the Submit-sized limit for each of them otherwise.
                if let Some(len) = len.filter(|&l| l > MAX_REQUEST_BYTES as u64) {
                    let refused = Status::out_of_range(format!(
                        "a request of {len} bytes; this call takes at most {MAX_REQUEST_BYTES}"
                    ));
                    return Ok(refused.into_http::<Body>());
                }
                let body = Body::new(Prefixed { read, rest: body });
                return inner.call(Request::from_parts(parts, body)).await;
            }
            // Past the message limit, tonic refuses it from the same prefix (OUT_OF_RANGE).
            let Some(len) = len.filter(|&l| l <= super::MAX_MESSAGE_BYTES as u64) else {
                let body = Body::new(Prefixed { read, rest: body });
                return inner.call(Request::from_parts(parts, body)).await;
            };
            let _reservation = match budget.admit_submission(len, transient_bytes(len)) {
                Ok(r) => r,
                Err(e) => return Ok(Status::resource_exhausted(e.to_string()).into_http::<Body>()),
            };
            // The whole message, as tonic would buffer it (the reservation covers it), then
            // its assets counted before prost makes one allocation per asset.
            let whole = 5 + len as usize;
            while have < whole {
                match body.frame().await {
                    Some(Ok(frame)) => {
                        have += frame.data_ref().map_or(0, Bytes::len);
                        read.push_back(frame);
                    }
                    _ => break,
                }
            }
            let data: Vec<Bytes> = read.iter().filter_map(|f| f.data_ref().cloned()).collect();
            if let Some(n) = scan::count_assets(&mut scan::Frames::new(&data, 5), len as usize) {
                if n > MAX_ASSETS as u64 {
                    let refused = Status::invalid_argument(format!(
                        "the bundle carries {n} assets, more than the limit of {MAX_ASSETS}"
                    ));
                    return Ok(refused.into_http::<Body>());
                }
            }
            drop(data);
            let body = Body::new(Prefixed { read, rest: body });
            inner.call(Request::from_parts(parts, body)).await
        })
    }
}

/// A body whose first frames were read already.
struct Prefixed {
    read: VecDeque<Frame<Bytes>>,
    rest: Body,
}

impl http_body::Body for Prefixed {
    type Data = Bytes;
    type Error = Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Status>>> {
        if let Some(frame) = self.read.pop_front() {
            return Poll::Ready(Some(Ok(frame)));
        }
        Pin::new(&mut self.rest).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.read.is_empty() && self.rest.is_end_stream()
    }
}
