//! A gate in front of `Submit`: at most `budget::SUBMITS_AT_ONCE` submissions are decoded
//! and validated at once. tonic buffers a request's message before the handler sees it, so
//! the gate must stand before tonic's own service: a submission waits here, with nothing of
//! its body read, until one in progress ends.

use std::convert::Infallible;
use std::sync::Arc;
use std::task::{Context, Poll};

use tokio::sync::Semaphore;
use tonic::body::Body;
use tonic::codegen::http::{Request, Response};
use tonic::codegen::{BoxFuture, Service};
use tonic::server::NamedService;

/// The path of the one gated method.
const SUBMIT: &str = "/tessera.v1.Coordinator/Submit";

/// `inner` with its `Submit` calls taken `permits` at a time.
#[derive(Clone)]
pub(super) struct SubmitGate<S> {
    inner: S,
    permits: Arc<Semaphore>,
}

impl<S> SubmitGate<S> {
    pub(super) fn new(inner: S, permits: Arc<Semaphore>) -> Self {
        SubmitGate { inner, permits }
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
        if request.uri().path() != SUBMIT {
            return Box::pin(inner.call(request));
        }
        let permits = self.permits.clone();
        Box::pin(async move {
            // Never closed, so acquiring only waits.
            let _permit = permits.acquire_owned().await;
            inner.call(request).await
        })
    }
}
