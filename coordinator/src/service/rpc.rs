//! The tonic trait: checks the caller's role (`auth::require`), then routes each RPC to its
//! family's handler.

use std::pin::Pin;
use std::time::Duration;

use tessera_proto::v1 as pb;
use tessera_proto::v1::coordinator_server::Coordinator;
use tessera_proto::v1::workers_server::Workers;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::Stream;
use tonic::{Request, Response, Status, Streaming};

use super::auth::{self, Action};
use super::viewers::WATCH_DEFAULT_RATE;
use super::workers::MAX_CREDIT;
use super::CoordinatorService;

/// A server stream of one message type.
pub(super) type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send + 'static>>;

/// Who a worker is, for strikes and quarantine (which outlive its connection): given the
/// name its `Hello` carries, the identity it is held to. With authentication, the
/// principal of its token or client certificate (so give each worker host its own token
/// or certificate: workers that share one are quarantined together); without, the remote
/// IP address and that name, so a quarantined worker that reconnects from the same host
/// under the same name is refused.
pub(super) fn worker_identity<T>(
    request: &Request<T>,
    authenticated: bool,
) -> impl FnOnce(&str) -> String + Send + 'static {
    let principal = if authenticated { auth::principal_name(request) } else { None };
    let ip = request.remote_addr().map(|a| a.ip());
    move |name: &str| match (principal, ip) {
        (Some(p), _) => format!("principal {p}"),
        (None, Some(ip)) => format!("{ip}/{name}"),
        (None, None) => format!("local/{name}"),
    }
}

#[tonic::async_trait]
impl Coordinator for CoordinatorService {
    type FetchImageStream = BoxStream<pb::ImageChunk>;
    type WatchStream = BoxStream<pb::FramebufferUpdate>;

    async fn watch(&self, request: Request<pb::WatchRequest>) -> Result<Response<Self::WatchStream>, Status> {
        let who = auth::require(&request, Action::Watch)?;
        let req = request.into_inner();
        // A viewer of another version could not read the pixels (one of version 1 sends 0).
        if req.protocol_version != pb::ProtocolVersion::Current as i32 {
            return Err(Status::failed_precondition(format!(
                "viewer speaks protocol version {}, coordinator {}: run the same tessera build",
                req.protocol_version,
                pb::ProtocolVersion::Current as i32
            )));
        }
        let job = self.pick_job(&who, req.job_id)?;
        self.check_owner(&who, job)?;
        let rate =
            if req.max_rate > 0.0 { req.max_rate.min(WATCH_DEFAULT_RATE * 10.0) } else { WATCH_DEFAULT_RATE };
        if !rate.is_finite() {
            return Err(Status::invalid_argument("max_rate must be a finite number"));
        }
        let interval = Duration::from_secs_f64(1.0 / rate.max(1.0 / 60.0));
        // One update in flight: a viewer that does not read holds one chunk, no backlog.
        let (tx, rx) = mpsc::channel(1);
        self.check_frame(job, req.frame)?;
        let sequence = self.farm().job(job).and_then(|j| Some((j.frames()?, j.frame_index(req.frame)?)));
        let slot = self.viewer_slot(job)?;
        // A sequence's viewers watch one frame each (frame_viewers.rs); a still's share its
        // publisher.
        let this = self.clone();
        tokio::spawn(async move {
            // The viewer's place is held until its task ends (it left, or the job is over).
            let _slot = slot;
            match sequence {
                Some(((first, _), index)) => {
                    this.feed_frame_viewer(job, first + index, index, interval, tx).await
                }
                None if req.previews => this.feed_preview_viewer(job, interval, tx).await,
                None => this.feed_viewer(job, interval, tx).await,
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn submit(
        &self,
        request: Request<pb::SubmitRequest>,
    ) -> Result<Response<pb::SubmitResponse>, Status> {
        auth::require(&request, Action::Submit)?;
        self.rpc_submit(request).await
    }

    async fn status(
        &self,
        request: Request<pb::StatusRequest>,
    ) -> Result<Response<pb::StatusResponse>, Status> {
        auth::require(&request, Action::Status)?;
        self.rpc_status(request).await
    }

    async fn fetch_image(
        &self,
        request: Request<pb::FetchImageRequest>,
    ) -> Result<Response<Self::FetchImageStream>, Status> {
        auth::require(&request, Action::FetchImage)?;
        self.rpc_fetch_image(request).await
    }

    async fn pause(&self, request: Request<pb::PauseRequest>) -> Result<Response<pb::PauseResponse>, Status> {
        auth::require(&request, Action::Pause)?;
        self.rpc_pause(request).await
    }

    async fn set_priority(
        &self,
        request: Request<pb::SetPriorityRequest>,
    ) -> Result<Response<pb::SetPriorityResponse>, Status> {
        auth::require(&request, Action::Prioritize)?;
        self.rpc_set_priority(request).await
    }

    async fn cancel(
        &self,
        request: Request<pb::CancelRequest>,
    ) -> Result<Response<pb::CancelResponse>, Status> {
        auth::require(&request, Action::Cancel)?;
        self.rpc_cancel(request).await
    }
}

#[tonic::async_trait]
impl Workers for CoordinatorService {
    type WorkStream = BoxStream<pb::CoordinatorMessage>;

    async fn work(
        &self,
        request: Request<Streaming<pb::WorkerMessage>>,
    ) -> Result<Response<Self::WorkStream>, Status> {
        auth::require(&request, Action::Work)?;
        let identity = worker_identity(&request, self.auth.required());
        let inbound = request.into_inner();
        // Room for a full credit's worth of batches plus scenes, so that handing out work
        // never waits on the worker reading.
        let (tx, rx) = mpsc::channel(MAX_CREDIT as usize + 16);
        tokio::spawn(self.clone().serve_worker(inbound, tx, identity));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }
}
