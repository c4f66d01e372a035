//! Client RPCs: submit, status, the image, pause and cancel.

use std::time::Instant;

use tessera_description::ids::JobId;
use tessera_proto::v1 as pb;
use tonic::{Request, Response, Status};
use tracing::info;

use super::auth;
use super::rpc::BoxStream;
use super::submit::SubmitFailure;
use crate::farm::SubmitError;
use tessera_proto::convert;

use super::CoordinatorService;

/// Pixels per `ImageChunk`: about 1 MB of floats at most, far below gRPC's message limit.
const ROWS_PER_CHUNK_PIXELS: usize = 1 << 16;

impl CoordinatorService {
    pub(super) async fn rpc_submit(
        &self,
        request: Request<pb::SubmitRequest>,
    ) -> Result<Response<pb::SubmitResponse>, Status> {
        let who = auth::caller(&request)?;
        self.check_priority(&who, request.get_ref().priority)?;
        let req = request.into_inner();
        if req.protocol_version != pb::ProtocolVersion::Current as i32 {
            return Err(Status::failed_precondition(format!(
                "client speaks protocol version {}, coordinator {}",
                req.protocol_version,
                pb::ProtocolVersion::Current as i32
            )));
        }
        let bundle = req.bundle.ok_or_else(|| Status::invalid_argument("submit without a scene bundle"))?;
        let settings = convert::settings_from_wire(req.settings.unwrap_or_default())
            .map_err(|e| Status::invalid_argument(e.to_string()))?;
        let id = self
            .submit_by(convert::bundle_from_wire(bundle), settings, req.priority, who.name)
            .await
            .map_err(|e| match e {
                SubmitFailure::Invalid(e @ SubmitError::OverBudget(_)) => {
                    Status::resource_exhausted(e.to_string())
                }
                SubmitFailure::Invalid(e) => Status::invalid_argument(e.to_string()),
                e @ SubmitFailure::Store(_) => Status::unavailable(e.to_string()),
            })?;
        let p = self.progress(id).ok_or_else(|| Status::not_found(format!("{id} ended before it began")))?;
        Ok(Response::new(pb::SubmitResponse { job_id: id.0, width: p.width, height: p.height, spp: p.spp }))
    }

    pub(super) async fn rpc_status(
        &self,
        request: Request<pb::StatusRequest>,
    ) -> Result<Response<pb::StatusResponse>, Status> {
        let who = auth::caller(&request)?;
        if request.get_ref().job_id != 0 {
            self.check_owner(&who, JobId(request.get_ref().job_id))?;
        }
        let want = request.into_inner().job_id;
        let farm = self.farm();
        let now = Instant::now();
        if want != 0 && farm.job(JobId(want)).is_none() {
            return Err(Status::not_found(format!("no job {want} on this coordinator")));
        }
        let jobs = farm
            .jobs()
            .filter(|j| (want == 0 || j.id.0 == want) && Self::sees_jobs_of(&who, &j.owner))
            .map(|j| pb::JobStatus {
                owner: j.owner.clone(),
                workers: farm.workers_on(j.id),
                ..convert::status_to_wire(&j.progress(now))
            })
            .collect();
        let workers = farm
            .workers()
            .map(|(id, w)| pb::WorkerStatus {
                worker_id: id.0,
                // A submitter learns that workers are there, not which machines they are.
                name: if who.role == auth::Role::Submitter { String::new() } else { w.name.clone() },
                threads: w.threads,
                batches_in_flight: farm.in_flight(id) as u32,
                batches_done: w.batches_done,
                strikes: farm.strikes(id),
                samples_per_second: w.samples_per_second(now),
                last_heard_seconds: w.last_heard(now).as_secs_f64(),
                ..Default::default()
            })
            .chain(super::workers::quarantined_to_wire(&farm).map(|mut q| {
                // Nor which identities are quarantined, or why.
                if who.role == auth::Role::Submitter {
                    q.name.clear();
                    q.quarantine_reason.clear();
                }
                q
            }))
            .collect();
        Ok(Response::new(pb::StatusResponse { jobs, workers }))
    }

    pub(super) async fn rpc_fetch_image(
        &self,
        request: Request<pb::FetchImageRequest>,
    ) -> Result<Response<BoxStream<pb::ImageChunk>>, Status> {
        self.check_owner(&auth::caller(&request)?, JobId(request.get_ref().job_id))?;
        let req = request.into_inner();
        let (id, frame, with_layers) = (JobId(req.job_id), req.frame, req.aovs);
        self.check_frame(id, frame)?;
        // A snapshot under the lock; the image is resolved outside it.
        let this = self.clone();
        let image = tokio::task::spawn_blocking(move || this.frame_image(id, frame, with_layers))
            .await
            .map_err(|e| Status::internal(format!("resolving the image failed: {e}")))?
            .ok_or_else(|| Status::not_found(format!("no {id} on this coordinator")))?;
        let frame = frame.unwrap_or_else(|| self.farm().job(id).and_then(|j| j.frames()).map_or(0, |f| f.0));
        let (width, height, rgb, state) =
            (image.width, image.height, image.rgb, convert::state_to_wire(&image.state));
        let layers = image.layers;
        // The same rows of a layer with `per` floats a pixel (empty if the job lacks it).
        let rows_of = |layer: &[f32], i: usize, rows: usize, per: usize| -> Vec<u8> {
            let (start, len) = (i * rows * width as usize * per, rows * width as usize * per);
            layer.iter().skip(start).take(len).flat_map(|v| v.to_le_bytes()).collect()
        };
        let rows_per_chunk = (ROWS_PER_CHUNK_PIXELS / width.max(1) as usize).max(1);
        let row_floats = width as usize * 3;
        let chunks: Vec<Result<pb::ImageChunk, Status>> = rgb
            .chunks(rows_per_chunk * row_floats)
            .enumerate()
            .map(|(i, rows)| {
                Ok(pb::ImageChunk {
                    albedo: rows_of(&layers.albedo, i, rows_per_chunk, 3),
                    normal: rows_of(&layers.normal, i, rows_per_chunk, 3),
                    depth: rows_of(&layers.depth, i, rows_per_chunk, 1),
                    width,
                    height,
                    row_start: (i * rows_per_chunk) as u32,
                    rows: (rows.len() / row_floats) as u32,
                    rgb: rows.iter().flat_map(|v| v.to_le_bytes()).collect(),
                    state: state as i32,
                    frame,
                })
            })
            .collect();
        Ok(Response::new(Box::pin(tokio_stream::iter(chunks))))
    }

    /// `NOT_FOUND` unless `job` exists and has `frame` (`None`: any job).
    pub(super) fn check_frame(&self, job: JobId, frame: Option<u32>) -> Result<(), Status> {
        let farm = self.farm();
        let Some(j) = farm.job(job) else {
            return Err(Status::not_found(format!("no {job} on this coordinator")));
        };
        if j.frame_index(frame).is_some() {
            return Ok(());
        }
        let f = frame.unwrap_or(0);
        Err(Status::not_found(match j.frames() {
            Some((first, last)) => format!("{job} has frames {first}-{last}, not frame {f}"),
            None => format!("{job} is a still image: it has no frame {f}"),
        }))
    }

    pub(super) async fn rpc_pause(
        &self,
        request: Request<pb::PauseRequest>,
    ) -> Result<Response<pb::PauseResponse>, Status> {
        self.check_owner(&auth::caller(&request)?, JobId(request.get_ref().job_id))?;
        let req = request.into_inner();
        let id = JobId(req.job_id);
        if !self.farm().set_paused(id, req.paused, Instant::now()) {
            return Err(Status::not_found(format!("no {id} on this coordinator")));
        }
        info!(%id, paused = req.paused, "job paused or resumed");
        self.notify();
        self.persist_state(id).await?;
        Ok(Response::new(pb::PauseResponse {}))
    }

    pub(super) async fn rpc_set_priority(
        &self,
        request: Request<pb::SetPriorityRequest>,
    ) -> Result<Response<pb::SetPriorityResponse>, Status> {
        let who = auth::caller(&request)?;
        self.check_owner(&who, JobId(request.get_ref().job_id))?;
        let req = request.into_inner();
        self.check_priority(&who, req.priority)?;
        let id = JobId(req.job_id);
        if !self.farm().set_priority(id, req.priority) {
            return Err(Status::not_found(format!("no {id} on this coordinator")));
        }
        info!(%id, priority = req.priority, "job priority changed");
        self.notify();
        self.persist_priority(id, req.priority).await?;
        Ok(Response::new(pb::SetPriorityResponse {}))
    }

    pub(super) async fn rpc_cancel(
        &self,
        request: Request<pb::CancelRequest>,
    ) -> Result<Response<pb::CancelResponse>, Status> {
        self.check_owner(&auth::caller(&request)?, JobId(request.get_ref().job_id))?;
        let id = JobId(request.into_inner().job_id);
        if !self.farm().cancel(id, Instant::now()) {
            return Err(Status::not_found(format!("no {id} on this coordinator")));
        }
        info!(%id, "job cancelled");
        self.notify();
        self.persist_state(id).await?;
        Ok(Response::new(pb::CancelResponse {}))
    }
}
