//! End-to-end: budgets and oversized input against a real coordinator process. Each
//! oversized input is refused with a one-line error saying what and where, nothing aborts
//! or hangs, and the coordinator's peak memory (VmHWM) stays within its configured budget
//! while everyone else keeps being served.

mod common;

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use prost::Message;
use tessera_proto::connect::Channel;
use tessera_proto::connect::EndpointConfig;
use tessera_proto::v1 as pb;
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};

const MB: u64 = 1 << 20;
const SMALL: &str = include_str!("scenes/small.toml");

fn bundle(name: &str, text: &str, assets: Vec<(&str, Vec<u8>)>) -> pb::SceneBundle {
    pb::SceneBundle {
        name: name.into(),
        text: text.into(),
        assets: assets.into_iter().map(|(p, d)| pb::Asset { path: p.into(), data: d }).collect(),
    }
}

fn request(b: pb::SceneBundle, width: u32, height: u32) -> pb::SubmitRequest {
    pb::SubmitRequest {
        protocol_version: pb::ProtocolVersion::Current as i32,
        bundle: Some(b),
        settings: Some(pb::RenderSettings { spp: 1, width, height, ..Default::default() }),
        priority: 0,
    }
}

async fn client(url: &str) -> pb::coordinator_client::CoordinatorClient<Channel> {
    // Large enough to send what the coordinator must refuse.
    let config = EndpointConfig::new(url).unwrap().max_message_bytes(1 << 30);
    tessera_proto::connect::client(&config).await.unwrap()
}

/// Peak and current resident memory of a process, in bytes (`VmHWM`, `VmRSS`).
fn memory_of(pid: u32) -> (u64, u64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let field = |name: &str| -> u64 {
        let line = status.lines().find(|l| l.starts_with(name)).unwrap();
        line.split_whitespace().nth(1).unwrap().parse::<u64>().unwrap() * 1024
    };
    (field("VmHWM:"), field("VmRSS:"))
}

/// A PNG header declaring `width × height`, with `idat` as its data.
fn png_declaring(width: u32, height: u32, idat: &[u8]) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
            }
        }
        !crc
    }
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    for (kind, data) in [
        (&b"IHDR"[..], [&width.to_be_bytes()[..], &height.to_be_bytes(), &[8, 2, 0, 0, 0]].concat()),
        (b"IDAT", idat.to_vec()),
        (b"IEND", vec![]),
    ] {
        png.extend((data.len() as u32).to_be_bytes());
        let body = [kind, &data].concat();
        png.extend(&body);
        png.extend(crc32(&body).to_be_bytes());
    }
    png
}

/// Every class of oversized scene input, over the wire: each refused with its code and a
/// one-line message naming what and where, and the coordinator answers Status after.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_submissions_are_refused_with_one_line_errors() {
    let coord = Coordinator::start(&["--memory-budget", "256M"]);
    let mut c = client(&coord.url).await;
    let refuse = |r: Result<tonic::Response<pb::SubmitResponse>, tonic::Status>| {
        let e = r.expect_err("refused");
        assert!(!e.message().contains('\n'), "one line: {:?}", e.message());
        (e.code(), e.message().to_string())
    };
    use tonic::Code::{InvalidArgument, OutOfRange, ResourceExhausted};

    // The largest legal image needs 9.6 GB of framebuffer: refused, not allocated.
    let (code, m) = refuse(c.submit(request(bundle("small.toml", SMALL, vec![]), 16384, 16384)).await);
    assert_eq!(code, ResourceExhausted);
    assert!(
        m.starts_with("\"small.toml\" needs 9937 MB of coordinator memory (16384x16384 framebuffer 9937 MB"),
        "{m}"
    );
    // A scene text over 16 MiB, refused before the TOML parser sees it.
    let text = format!("{SMALL}#{}\n", "x".repeat(17 << 20));
    let (code, m) = refuse(c.submit(request(bundle("huge.toml", &text, vec![]), 0, 0)).await);
    assert_eq!(code, InvalidArgument);
    assert!(
        m.starts_with("huge.toml:1:1: the scene file is 178")
            && m.ends_with("more than the limit of 16777216; put geometry in mesh files"),
        "{m}"
    );
    // A long line, at its line.
    let text = format!("{SMALL}# {}\n", "x".repeat(70_000));
    let (_, m) = refuse(c.submit(request(bundle("long.toml", &text, vec![]), 0, 0)).await);
    let line = SMALL.lines().count() + 1;
    assert!(
        m.starts_with(&format!("long.toml:{line}:1: the line is 70002 bytes, more than the limit of 65536")),
        "{m}"
    );
    // A 60 MB scene name, quoted 80 bytes at most.
    let name = "n".repeat(60 << 20);
    let (_, m) = refuse(c.submit(request(bundle(&name, SMALL, vec![]), 0, 0)).await);
    assert!(
        m.len() < 300 && m.contains("the scene's name is 62914560 bytes, more than the limit of 1024"),
        "{m}"
    );
    // An asset the scene does not use, named.
    let (_, m) = refuse(
        c.submit(request(bundle("small.toml", SMALL, vec![("junk.bin", vec![0; 1 << 20])]), 0, 0)).await,
    );
    assert_eq!(m, "small.toml:1:1: the bundle carries assets the scene does not use: \"junk.bin\"");
    // A 0.4 MB PNG declaring 12000x12000, from its header.
    let tex = format!("{SMALL}\n[textures.big]\ntype = \"image\"\nfile = \"big.png\"\n");
    let png = png_declaring(12_000, 12_000, &vec![0; 400_000]);
    let (_, m) = refuse(c.submit(request(bundle("tex.toml", &tex, vec![("big.png", png)]), 0, 0)).await);
    assert!(m.ends_with("textures.big.file: \"big.png\" is 12000x12000, more than the limit of 67108864 pixels for a texture"), "{m}");
    // An OBJ face with more corners than any face may have.
    let mesh = format!("{SMALL}\n[[mesh]]\nfile = \"m.obj\"\nmaterial = \"floor\"\n");
    let obj = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nf{}\n", " 1".repeat(1_000_000));
    let (_, m) =
        refuse(c.submit(request(bundle("mesh.toml", &mesh, vec![("m.obj", obj.into_bytes())]), 0, 0)).await);
    assert!(m.ends_with("mesh \"m.obj\": line 4: a face has more than 4096 corners"), "{m}");
    // A message over the bundle limit: refused by its length prefix, before it is buffered.
    let big = vec![0; 300 << 20];
    let (code, m) =
        refuse(c.submit(request(bundle("small.toml", SMALL, vec![("big.bin", big)]), 0, 0)).await);
    assert_eq!(code, OutOfRange, "{m}");

    // Jobs that fit one by one, until the budget is spent: the fourth 1920x1080 is refused.
    for _ in 0..3 {
        c.submit(request(bundle("small.toml", SMALL, vec![]), 1920, 1080)).await.unwrap();
    }
    let (code, m) = refuse(c.submit(request(bundle("small.toml", SMALL, vec![]), 1920, 1080)).await);
    assert_eq!(code, ResourceExhausted);
    assert!(m.contains("of the budget of 269 MB are free"), "{m}");

    // Still serving, and Status stays small.
    let status = c.status(pb::StatusRequest { job_id: 0 }).await.unwrap().into_inner();
    assert_eq!(status.jobs.len(), 3);
    assert!(status.encoded_len() < 4096);
}

/// Sends pre-encoded bytes as messages, to craft what a well-behaved client would not.
#[derive(Clone, Default)]
struct Raw;
struct RawEncoder;
struct MessageDecoder;

impl Codec for Raw {
    type Encode = Vec<u8>;
    type Decode = pb::CoordinatorMessage;
    type Encoder = RawEncoder;
    type Decoder = MessageDecoder;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> MessageDecoder {
        MessageDecoder
    }
}

impl Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), tonic::Status> {
        use prost::bytes::BufMut;
        dst.put_slice(&item);
        Ok(())
    }
}

impl Decoder for MessageDecoder {
    type Item = pb::CoordinatorMessage;
    type Error = tonic::Status;
    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<pb::CoordinatorMessage>, tonic::Status> {
        pb::CoordinatorMessage::decode(src).map(Some).map_err(|e| tonic::Status::internal(e.to_string()))
    }
}

/// A `WorkerMessage` of `bytes` packed zero varints: a `Results` whose one result's sums
/// are all zero (each inflates from 1 byte on the wire to 8 in memory).
fn packed_zeros(bytes: usize) -> Vec<u8> {
    fn varint(mut v: u64, out: &mut Vec<u8>) {
        while v >= 0x80 {
            out.push((v as u8) | 0x80);
            v >>= 7;
        }
        out.push(v as u8);
    }
    let mut result = Vec::with_capacity(bytes + 32);
    result.push(4 << 3 | 2); // BatchResult.sums, packed
    varint(bytes as u64, &mut result);
    result.resize(result.len() + bytes, 0);
    let mut results = vec![1 << 3 | 2]; // Results.results
    varint(result.len() as u64, &mut results);
    results.extend(result);
    let mut msg = vec![2 << 3 | 2]; // WorkerMessage.results
    varint(results.len() as u64, &mut msg);
    msg.extend(results);
    msg
}

/// Opens a work stream that says Hello and then sends `then`; returns what the
/// coordinator answered after Hello (`None`: it closed or failed the stream).
async fn work_stream(url: &str, then: Vec<u8>) -> Option<pb::CoordinatorMessage> {
    let channel = tessera_proto::connect::connect(&EndpointConfig::new(url).unwrap()).await.unwrap();
    let mut grpc = tonic::client::Grpc::new(channel).max_encoding_message_size(1 << 30);
    grpc.ready().await.unwrap();
    let hello = pb::WorkerMessage {
        msg: Some(pb::worker_message::Msg::Hello(pb::Hello {
            protocol_version: pb::ProtocolVersion::Current as i32,
            renderer_version: tessera_worker::RENDERER_VERSION.into(),
            name: "hostile".into(),
            threads: 1,
            credit: 0,
            frames: true,
            held_scenes: vec![],
        })),
    };
    let out = tokio_stream::iter(vec![hello.encode_to_vec(), then]);
    let path = tonic::codegen::http::uri::PathAndQuery::from_static("/tessera.v1.Workers/Work");
    let mut inbound = grpc.streaming(tonic::Request::new(out), path, Raw).await.ok()?.into_inner();
    let welcome = inbound.message().await.ok()??;
    assert!(matches!(welcome.msg, Some(pb::coordinator_message::Msg::Welcome(_))), "{welcome:?}");
    tokio::time::timeout(Duration::from_secs(20), inbound.message()).await.expect("no hang").ok().flatten()
}

/// A results message of 200 MB of packed zeros is refused by its length, before it is
/// buffered or inflated; the coordinator stays small and serves on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_worker_messages_are_refused_before_they_inflate() {
    let coord = Coordinator::start(&["--memory-budget", "64M"]);
    let before = memory_of(coord.proc.pid()).0;
    let answered = work_stream(&coord.url, packed_zeros(200 << 20)).await;
    assert!(answered.is_none(), "{answered:?}");
    coord.proc.wait_for("worker left (lost)", Duration::from_secs(20));
    let after = memory_of(coord.proc.pid()).0;
    assert!(after < before + 32 * MB, "VmHWM {} -> {} MB", before / MB, after / MB);
    let status = client(&coord.url).await.status(pb::StatusRequest { job_id: 0 }).await;
    assert!(status.unwrap().into_inner().workers.is_empty(), "still serving, the sender gone");
}

/// A worker whose memory is smaller than a scene's estimate refuses it with
/// `BatchFailed { scene_refused: true }`, naming the scene and both figures.
#[test]
fn a_worker_refuses_a_scene_over_its_memory() {
    let coord = Coordinator::start(&[]);
    let worker = Proc::spawn(&["worker", "--coordinator", &coord.url, "--threads", "1", "--memory", "1000"]);
    worker.wait_for("connected to", Duration::from_secs(30));
    let out = run(&["submit", "--coordinator", &coord.url, small_scene().to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let line = worker.wait_for("cannot render batch", Duration::from_secs(30));
    // Without the log's colours.
    let mut plain = String::new();
    let mut chars = line.chars();
    while let Some(ch) = chars.next() {
        if ch == '\u{1b}' {
            chars.by_ref().find(|c| c.is_ascii_alphabetic());
        } else {
            plain.push(ch);
        }
    }
    let line = plain;
    assert!(line.contains("scene_refused=true"), "{line}");
    assert!(
        line.contains("small.toml: the scene needs about ")
            && line.contains("more than this worker's 1000 (--memory)"),
        "{line}"
    );
}

/// The coordinator's peak memory stays within its budget (plus the process's own base)
/// under concurrent oversized submissions, 1000 Watch streams opened and dropped, and
/// oversized worker messages, while a normal client's Status keeps being answered.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_coordinator_stays_within_its_budget_under_attack() {
    const BUDGET: u64 = 192 * MB;
    let coord = Coordinator::start(&["--memory-budget", "192M"]);
    let pid = coord.proc.pid();
    let mut c = client(&coord.url).await;
    let watched =
        c.submit(request(bundle("small.toml", SMALL, vec![]), 64, 48)).await.unwrap().into_inner().job_id;
    let base = memory_of(pid).0;

    // A normal client polls Status throughout; its slowest answer is kept.
    let stop = Arc::new(AtomicBool::new(false));
    let slowest = Arc::new(AtomicU64::new(0));
    // On a thread and runtime of its own, so that the attackers' work in this process
    // cannot delay it.
    let poller = {
        let (url, stop, slowest) = (coord.url.clone(), stop.clone(), slowest.clone());
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
            rt.block_on(async move {
                let mut c = client(&url).await;
                let mut answers = 0u32;
                while !stop.load(Ordering::Relaxed) {
                    let t = Instant::now();
                    c.status(pb::StatusRequest { job_id: 0 }).await.expect("Status answered");
                    slowest.fetch_max(t.elapsed().as_millis() as u64, Ordering::Relaxed);
                    answers += 1;
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
                answers
            })
        })
    };

    let mut attacks = Vec::new();
    // Oversized submissions, concurrently: over the budget, over the message limit, and
    // bundles carrying 20 MB of unused assets.
    for i in 0..6u32 {
        let url = coord.url.clone();
        attacks.push(tokio::spawn(async move {
            let mut c = client(&url).await;
            let r = match i % 3 {
                0 => c.submit(request(bundle("small.toml", SMALL, vec![]), 16384, 16384)).await,
                1 => {
                    c.submit(request(
                        bundle("small.toml", SMALL, vec![("big.bin", vec![1; 300 << 20])]),
                        0,
                        0,
                    ))
                    .await
                }
                _ => {
                    c.submit(request(
                        bundle("small.toml", SMALL, vec![("junk.bin", vec![1; 20 << 20])]),
                        0,
                        0,
                    ))
                    .await
                }
            };
            assert!(r.is_err(), "attack {i} refused");
        }));
    }
    // 1000 Watch streams over ten connections, opened, read once and dropped.
    for _ in 0..10 {
        let url = coord.url.clone();
        attacks.push(tokio::spawn(async move {
            let c = client(&url).await;
            let mut streams = Vec::new();
            let mut refused = 0;
            for k in 0..100 {
                let req = pb::WatchRequest {
                    job_id: watched,
                    max_rate: 0.0,
                    protocol_version: pb::ProtocolVersion::Current as i32,
                    frame: None,
                    // Both kinds of viewer: exact replicas and previews.
                    previews: k % 2 == 0,
                };
                match c.clone().watch(req).await {
                    Ok(s) => streams.push(s.into_inner()),
                    Err(e) => {
                        assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e}");
                        refused += 1;
                    }
                }
            }
            for s in &mut streams {
                let _ = tokio::time::timeout(Duration::from_secs(5), s.message()).await;
            }
            // All watch one job: at most its limit of viewers at once.
            assert!(streams.len() <= tessera_coordinator::service::MAX_VIEWERS_PER_JOB, "{}", streams.len());
            assert_eq!(streams.len() + refused, 100);
            drop(streams);
        }));
    }
    // Oversized worker messages.
    for _ in 0..4 {
        let url = coord.url.clone();
        attacks.push(tokio::spawn(async move {
            assert!(work_stream(&url, packed_zeros(150 << 20)).await.is_none());
        }));
    }
    for a in attacks {
        a.await.unwrap();
    }
    stop.store(true, Ordering::Relaxed);
    let answers = poller.join().unwrap();
    let (peak, now) = memory_of(pid);
    eprintln!(
        "VmHWM {} MB (base {} MB, budget {} MB), VmRSS now {} MB; Status answered {answers} times, slowest {} ms",
        peak / MB,
        base / MB,
        BUDGET / MB,
        now / MB,
        slowest.load(Ordering::Relaxed)
    );
    assert!(peak < BUDGET, "VmHWM {} MB over the budget of {} MB", peak / MB, BUDGET / MB);
    assert!(answers > 10 && slowest.load(Ordering::Relaxed) < 2000);
    // The viewers that were accepted gave their places back.
    let mut w = client(&coord.url).await;
    let ok = w
        .watch(pb::WatchRequest {
            job_id: watched,
            max_rate: 0.0,
            protocol_version: pb::ProtocolVersion::Current as i32,
            frame: None,
            previews: false,
        })
        .await;
    assert!(ok.is_ok(), "a viewer is accepted after the others left");
}

/// A work stream that never says Hello is closed after the worker timeout, not kept.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_work_stream_without_hello_is_closed() {
    let coord = Coordinator::start(&["--worker-timeout", "1"]);
    let channel = tessera_proto::connect::connect(&EndpointConfig::new(&coord.url).unwrap()).await.unwrap();
    let (_tx, rx) = tokio::sync::mpsc::channel::<pb::WorkerMessage>(1);
    let mut client = pb::workers_client::WorkersClient::new(channel);
    let start = Instant::now();
    let mut inbound =
        client.work(tokio_stream::wrappers::ReceiverStream::new(rx)).await.unwrap().into_inner();
    let end =
        tokio::time::timeout(Duration::from_secs(10), inbound.message()).await.expect("closed, not kept");
    assert!(matches!(end, Ok(None) | Err(_)), "{end:?}");
    assert!(start.elapsed() >= Duration::from_millis(900), "{:?}", start.elapsed());
}

/// A submission whose decoding and validation would not fit what is left of the budget is
/// refused from its length prefix, before its body is read.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_submission_that_cannot_be_decoded_within_the_budget_is_refused_unread() {
    let coord = Coordinator::start(&["--memory-budget", "64M"]);
    let mut c = client(&coord.url).await;
    let before = memory_of(coord.proc.pid()).0;
    let junk = vec![1; 30 << 20];
    let e = c.submit(request(bundle("small.toml", SMALL, vec![("junk.bin", junk)]), 0, 0)).await.unwrap_err();
    assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{e}");
    assert!(e.message().starts_with("a submission of 32 MB needs up to 181 MB of coordinator memory to decode and validate, but 68 MB of the budget of 68 MB are free"), "{}", e.message());
    let after = memory_of(coord.proc.pid()).0;
    assert!(
        after < before + 16 * MB,
        "VmHWM {} -> {} MB: the body was not buffered",
        before / MB,
        after / MB
    );
    // A small one still goes through.
    c.submit(request(bundle("small.toml", SMALL, vec![]), 0, 0)).await.unwrap();
}
