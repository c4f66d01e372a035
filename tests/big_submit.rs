//! End-to-end: a huge scene submitted to a standalone coordinator does not stop it from
//! answering Status while it validates the scene (outside the farm's lock). No wall-time
//! threshold: the test checks orderings and counts; the figures are `tessera bench submit`'s.
//! Validation is held open by the coordinator's stall hook (`FAULT_STALL_VALIDATION_ENV`)
//! for a second inside validation: how long the scan itself takes depends on the machine and
//! the profile (tens of milliseconds optimised, too short a window to count calls in).

mod common;

use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use tessera_description::bundle::Bundle;
use tessera_proto::connect::EndpointConfig;
use tessera_proto::v1 as pb;

/// Triangles of the one OBJ grid, and the meshes that use it: the bundle carries the mesh
/// once (10 MB) while validation scans it for every use.
const TRIANGLES: usize = 300_000;
const MESHES: usize = 24;
/// The image, which no figure of the listed job may depend on the triangles for.
const WIDTH: u32 = 64;
const HEIGHT: u32 = 48;
const SPP: u32 = 8;
/// What the coordinator logs as it starts validating a submitted scene.
const VALIDATING: &str = "validating a submitted scene";
/// How long the hook holds validation open: a hundred polls' worth.
const STALL_MS: &str = "1000";

/// Writes grid.obj (a regular grid of `TRIANGLES` triangles) and scene.toml using it
/// `MESHES` times; returns the scene's path.
fn write_scene(dir: &Path) -> std::path::PathBuf {
    let cols = ((TRIANGLES / 2) as f64).sqrt().ceil() as usize;
    let rows = (TRIANGLES / 2).div_ceil(cols);
    let mut obj = std::io::BufWriter::new(std::fs::File::create(dir.join("grid.obj")).unwrap());
    for j in 0..=rows {
        for i in 0..=cols {
            writeln!(obj, "v {:.5} 0 {:.5}", i as f64 / cols as f64, j as f64 / rows as f64).unwrap();
        }
    }
    let vertex = |i: usize, j: usize| 1 + j * (cols + 1) + i;
    for k in 0..TRIANGLES / 2 {
        let (i, j) = (k % cols, k / cols);
        let (a, b, c, d) = (vertex(i, j), vertex(i + 1, j), vertex(i + 1, j + 1), vertex(i, j + 1));
        writeln!(obj, "f {a} {b} {c}\nf {a} {c} {d}").unwrap();
    }
    obj.flush().unwrap();
    let mut text = format!(
        "[render]\nwidth = {WIDTH}\nheight = {HEIGHT}\nspp = {SPP}\n\n\
         [camera]\nposition = [0, 8, 14]\nlook_at = [0, 0, -3]\n\n\
         [materials.grey]\ntype = \"lambert\"\n\n"
    );
    for k in 0..MESHES {
        let (x, z, turn) = ((k % 6) as f64 * 2.2 - 5.5, (k / 6) as f64 * -2.2, k * 15);
        text.push_str(&format!(
            "[[mesh]]\nfile = \"grid.obj\"\nmaterial = \"grey\"\n\
             transform = {{ translate = [{x:.2}, 0, {z:.2}], rotate = [0, {turn}, 0] }}\n\n"
        ));
    }
    text.push_str("[[point_light]]\nposition = [3, 10, 6]\nintensity = 150\n");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, text).unwrap();
    scene
}

#[test]
fn status_answers_while_a_huge_scene_is_validated() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = Bundle::read(&write_scene(dir.path())).unwrap();
    assert_eq!(bundle.assets.len(), 1, "the mesh travels once");
    let stall = [(tessera_coordinator::service::FAULT_STALL_VALIDATION_ENV, STALL_MS)];
    let coord = Coordinator::start_at("127.0.0.1:0", &[], &stall);
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(async {
        let config = EndpointConfig::new(&coord.url).unwrap();
        let mut submitter = tessera_proto::connect::client(&config).await.unwrap();
        // Its own connection, as a separate `tessera status` process has; opened first, so
        // that connecting is not what the count measures.
        let mut poller = tessera_proto::connect::client(&config).await.unwrap();
        poller.status(pb::StatusRequest { job_id: 0 }).await.unwrap();
        let request = pb::SubmitRequest {
            protocol_version: tessera_proto::PROTOCOL_VERSION as i32,
            bundle: Some(tessera_proto::convert::bundle_to_wire(&bundle)),
            settings: Some(pb::RenderSettings::default()),
            priority: 0,
        };
        let submitted = Arc::new(AtomicBool::new(false));
        let polling = tokio::spawn({
            let (submitted, mut poller, log) = (submitted.clone(), poller.clone(), coord.proc.stderr.clone());
            async move {
                // (validating, answered, jobs listed) of each call made until the submit
                // returned; validating: the coordinator had logged that it started
                // validating before the call was sent.
                let mut calls = Vec::new();
                while !submitted.load(Ordering::SeqCst) {
                    let validating = log.lock().unwrap().contains(VALIDATING);
                    let r = poller.status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner();
                    calls.push((validating, Instant::now(), r.jobs.len()));
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
                calls
            }
        });
        let response = submitter.submit(request).await.unwrap().into_inner();
        let done = Instant::now();
        submitted.store(true, Ordering::SeqCst);
        let calls = polling.await.unwrap();
        // Sent once validation had begun, answered strictly before the Submit response and
        // listing no job yet (it enters the farm once valid): answered during validation.
        // Calls are sequential, so were validation under the farm's lock, at most one
        // call (the one it blocked) would count.
        let during = calls.iter().filter(|&&(v, answered, jobs)| v && answered < done && jobs == 0).count();
        assert!(
            during >= 3,
            "only {during} of {} Status calls were answered while the scene was validated",
            calls.len()
        );

        let listed = poller.status(pb::StatusRequest { job_id: response.job_id }).await.unwrap().into_inner();
        assert_eq!(listed.jobs.len(), 1, "{listed:?}");
        let job = &listed.jobs[0];
        assert_eq!((response.width, response.height, response.spp), (WIDTH, HEIGHT, SPP));
        assert_eq!((job.width, job.height, job.spp), (WIDTH, HEIGHT, SPP), "{job:?}");
        assert_eq!(job.samples_total, u64::from(WIDTH * HEIGHT * SPP), "{job:?}");
        assert_eq!((job.samples_done, job.pass_one_done), (0, 0), "no worker: {job:?}");
        assert_eq!(tessera_proto::convert::state_name(job.state), "queued", "{job:?}");
    });
}
