//! End-to-end: the web dashboard in a real browser. Headless Chromium (Debian's package,
//! made available by `scripts/chromium.sh`) is driven over the DevTools protocol against a
//! real `tessera coordinator --http` with tokens and real `tessera worker`s: it logs in,
//! submits scenes through the page's form (a scene with a mesh and a texture among them),
//! watches a job's live canvas show the mosaic and then the final image pixel for pixel,
//! pauses and resumes it, and cancels another from the jobs table.
//!
//! `TESSERA_SCREENSHOTS=1` also saves `docs/images/dashboard-jobs.png` and
//! `docs/images/dashboard-job.png` (so that ordinary runs leave the tree clean).

mod common;

use base64::Engine as _;
use common::*;
use headless_chrome::browser::tab::point::Point;
use headless_chrome::protocol::cdp::Input;
use headless_chrome::protocol::cdp::Page::CaptureScreenshotFormatOption;
use headless_chrome::{Browser, LaunchOptions, Tab};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

const ADMIN_TOKEN: &str = "admin-token-0123456789abcdef";
/// Samples per pixel of job 1 (the mesh at 400×300): enough that it is still rendering
/// when the test pauses it at a quarter, however fast the tracer.
const JOB1_SPP: u64 = 64;
const VIEWER_TOKEN: &str = "viewer-token-0123456789abcdef";
const WORKER_TOKEN: &str = "worker-token-0123456789abcdef";

/// The browser from `scripts/chromium.sh`, or why there is none.
fn chromium() -> Result<PathBuf, String> {
    let out = std::process::Command::new("bash")
        .arg(root().join("scripts/chromium.sh"))
        .output()
        .map_err(|e| format!("cannot run scripts/chromium.sh: {e}"))?;
    if out.status.success() {
        let path = String::from_utf8_lossy(&out.stdout).trim().to_string();
        return Ok(PathBuf::from(path));
    }
    let why = String::from_utf8_lossy(&out.stderr).trim().to_string();
    Err(if why.is_empty() { format!("scripts/chromium.sh failed ({})", out.status) } else { why })
}

/// A page in the browser, with the few things the test does to it.
struct Page {
    tab: Arc<Tab>,
    base: String,
}

impl Page {
    fn open(&self, path: &str) {
        self.tab.navigate_to(&format!("{}{path}", self.base)).unwrap();
        self.tab.wait_until_navigated().unwrap();
    }

    /// The JSON value of a JavaScript expression (a promise is awaited).
    fn js(&self, expr: &str) -> serde_json::Value {
        self.try_js(expr).unwrap_or_else(|e| panic!("evaluating {expr}: {e}"))
    }

    /// The same, or why it could not be evaluated (e.g. the page is being replaced).
    fn try_js(&self, expr: &str) -> Result<serde_json::Value, String> {
        let wrapped =
            format!("Promise.resolve({expr}).then((v) => JSON.stringify(v === undefined ? null : v))");
        let r = self.tab.evaluate(&wrapped, true).map_err(|e| e.to_string())?;
        let text = r
            .value
            .and_then(|v| v.as_str().map(str::to_string))
            .ok_or_else(|| format!("no value: {:?}", r.description.or(r.unserializable_value)))?;
        serde_json::from_str(&text).map_err(|e| e.to_string())
    }

    /// Waits until `expr` is true; panics with `what` and `detail` (an expression shown
    /// when it is not) after `limit`.
    fn wait(&self, expr: &str, limit: Duration, what: &str, detail: &str) {
        let start = Instant::now();
        while self.try_js(expr) != Ok(serde_json::Value::Bool(true)) {
            if start.elapsed() > limit {
                panic!("{what}: not within {limit:?}; {:?}", self.try_js(detail));
            }
            std::thread::sleep(Duration::from_millis(25));
        }
    }

    /// Clicks the middle of the element `selector` with the mouse, as a user would.
    fn click(&self, selector: &str) {
        // headless_chrome's Element::click polls the layout and takes about a second a
        // click on a busy machine; the point from the page itself, then three events.
        let at = self.js(&format!(
            "(() => {{ const e = document.querySelector({selector:?}); if (!e) return null;
               e.scrollIntoView({{ block: 'center' }}); const r = e.getBoundingClientRect();
               return [r.x + r.width / 2, r.y + r.height / 2]; }})()"
        ));
        assert!(at.is_array(), "no {selector} to click");
        let point = Point { x: at[0].as_f64().unwrap(), y: at[1].as_f64().unwrap() };
        self.tab.click_point(point).unwrap();
    }

    /// Types `text` into the input `selector` (focused and emptied first), as one input.
    fn fill(&self, selector: &str, text: &str) {
        let found = self.js(&format!(
            "(() => {{ const e = document.querySelector({selector:?}); if (!e) return false;
               e.focus(); e.value = ''; return true; }})()"
        ));
        assert_eq!(found, true, "no {selector} to type into");
        if !text.is_empty() {
            self.tab.call_method(Input::InsertText { text: text.to_string() }).unwrap();
        }
    }

    fn pick_files(&self, selector: &str, files: &[&Path]) {
        let paths: Vec<&str> = files.iter().map(|p| p.to_str().unwrap()).collect();
        self.tab.wait_for_element(selector).unwrap().set_input_files(&paths).unwrap();
    }

    /// The canvas's pixels, read back through the 2D context: RGBA8, row 0 on top.
    fn canvas(&self) -> (u32, u32, Vec<u8>) {
        let v = self.js(
            "(() => { const c = document.getElementById('live');
               const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
               let s = ''; for (let i = 0; i < d.length; i += 0x8000) s += String.fromCharCode.apply(null, d.subarray(i, i + 0x8000));
               return [c.width, c.height, btoa(s)]; })()",
        );
        let bytes = base64::engine::general_purpose::STANDARD.decode(v[2].as_str().unwrap()).unwrap();
        (v[0].as_u64().unwrap() as u32, v[1].as_u64().unwrap() as u32, bytes)
    }

    /// `GET path` from the page (with its session cookie), decoded as an image: RGBA8.
    fn image(&self, path: &str) -> (u32, u32, Vec<u8>) {
        let v = self.js(&format!(
            "fetch({path:?}).then(async (r) => {{
               if (!r.ok) return 'HTTP ' + r.status + ': ' + await r.text();
               const d = new Uint8Array(await r.arrayBuffer());
               let s = ''; for (let i = 0; i < d.length; i += 0x8000) s += String.fromCharCode.apply(null, d.subarray(i, i + 0x8000));
               return btoa(s); }})"
        ));
        let text = v.as_str().unwrap();
        assert!(!text.starts_with("HTTP "), "GET {path}: {text}");
        let png = base64::engine::general_purpose::STANDARD.decode(text).unwrap();
        let img = image::load_from_memory(&png)
            .unwrap_or_else(|e| panic!("GET {path}: not an image: {e}"))
            .to_rgba8();
        (img.width(), img.height(), img.into_raw())
    }

    fn screenshot(&self, name: &str) {
        if std::env::var_os("TESSERA_SCREENSHOTS").is_none() {
            return;
        }
        let png = self.tab.capture_screenshot(CaptureScreenshotFormatOption::Png, None, None, true).unwrap();
        let path = root().join("docs/images").join(name);
        std::fs::write(&path, png).unwrap();
        eprintln!("saved {}", path.display());
    }

    /// The id of the job the submit form just submitted; panics with the form's error.
    fn submitted(&self, limit: Duration) -> u64 {
        let start = Instant::now();
        // The previous submission's link is removed when the button is pressed.
        loop {
            let v = self.js("[document.querySelector('[data-submitted]')?.dataset.submitted ?? null,
                  document.getElementById('submit-error').textContent]");
            if let Some(id) = v[0].as_str() {
                return id.parse().unwrap();
            }
            let error = v[1].as_str().unwrap();
            assert!(error.is_empty(), "the submit form says: {error}");
            assert!(start.elapsed() < limit, "no job submitted within {limit:?}");
            std::thread::sleep(Duration::from_millis(25));
        }
    }

    /// The job page's status figures.
    fn status(&self) -> serde_json::Value {
        self.js("({...document.getElementById('status-line').dataset})")
    }
}

/// The number of pixels whose bytes differ between two RGBA8 images of the same size.
fn differing(a: &[u8], b: &[u8]) -> usize {
    assert_eq!(a.len(), b.len(), "images of different sizes");
    a.chunks_exact(4).zip(b.chunks_exact(4)).filter(|(x, y)| x != y).count()
}

/// A coordinator serving the dashboard on a free loopback port: (gRPC URL, HTTP base URL).
fn coordinator(dir: &Path) -> (Proc, String, String) {
    let tokens = dir.join("tokens");
    write_secret(
        &tokens,
        &format!("admin alice {ADMIN_TOKEN}\nviewer wall {VIEWER_TOKEN}\nworker farm {WORKER_TOKEN}\n"),
    );
    let proc = Proc::spawn(&[
        "coordinator",
        "--listen",
        "127.0.0.1:0",
        "--http",
        "127.0.0.1:0",
        "--tokens",
        tokens.to_str().unwrap(),
    ]);
    let line = proc.wait_for("coordinator listening on ", Duration::from_secs(30));
    let grpc = format!("http://{}", line.rsplit("listening on ").next().unwrap().trim());
    let line = proc.wait_for("dashboard on ", Duration::from_secs(30));
    let http = line.rsplit("dashboard on ").next().unwrap().trim().trim_end_matches('/').to_string();
    (proc, grpc, http)
}

fn worker(grpc: &str, token_file: &Path) -> Proc {
    let w = Proc::spawn(&[
        "worker",
        "--coordinator",
        grpc,
        "--threads",
        "1",
        "--token-file",
        token_file.to_str().unwrap(),
    ]);
    w.wait_for("connected to", Duration::from_secs(30));
    w
}

/// The dashboard as a user meets it: login, submit through the form, a job's live canvas
/// (the mosaic early, the coordinator's exact image mid-render and at the end), pause and
/// resume, cancel from the jobs table, and what a viewer's role is shown. Protects the
/// pages against drifting from the HTTP contract and the live image from drawing
/// anything but the coordinator's pixels.
#[test]
fn the_dashboard_in_a_real_browser() {
    let browser_path = match chromium() {
        Ok(p) => p,
        Err(why) => {
            eprintln!("SKIPPED: {why}");
            return;
        }
    };
    let started = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let (coord, grpc, http) = coordinator(dir.path());
    let token_file = dir.path().join("worker.token");
    write_secret(&token_file, WORKER_TOKEN);

    let browser = Browser::new(LaunchOptions {
        path: Some(browser_path),
        headless: true,
        sandbox: false,
        window_size: Some((1440, 900)),
        idle_browser_timeout: Duration::from_secs(120),
        args: vec![std::ffi::OsStr::new("--force-device-scale-factor=1")],
        ..LaunchOptions::default()
    })
    .expect("headless Chromium starts");
    let tab = browser.new_tab().unwrap();
    tab.set_default_timeout(Duration::from_secs(20));
    let page = Page { tab, base: http.clone() };
    let long = Duration::from_secs(30);

    eprintln!("{:5.1} s: browser up", started.elapsed().as_secs_f64());
    // Not logged in: the login form, and a wrong token is refused with a message.
    page.open("/");
    page.wait(
        "!document.getElementById('login').hidden",
        long,
        "the login form",
        "document.body.outerHTML.slice(0, 400)",
    );
    page.fill("#login-token", "not-a-token-of-this-farm");
    page.click("#login-form button[type=submit]");
    page.wait(
        "document.getElementById('login-error').textContent.length > 0",
        long,
        "an error for a wrong token",
        "document.getElementById('login-error').textContent",
    );
    page.fill("#login-token", ADMIN_TOKEN);
    page.click("#login-form button[type=submit]");
    page.wait(
        "document.body.dataset.session === 'in'",
        long,
        "logged in",
        "document.getElementById('login-error').textContent",
    );
    assert_eq!(page.js("document.getElementById('who').textContent"), "alice · admin");

    eprintln!("{:5.1} s: logged in", started.elapsed().as_secs_f64());
    // Submit the mesh scene with its two assets picked as files (no folder: the page maps
    // them to the paths the scene names by file name), then a second, lower-priority job.
    let scenes = root().join("scenes");
    page.pick_files("#submit-scene", &[&scenes.join("mesh.toml")]);
    page.pick_files(
        "#submit-assets",
        &[&scenes.join("assets/torus_knot.obj"), &scenes.join("assets/penumbra_print.png")],
    );
    page.wait(
        "document.querySelectorAll('#submit-map li.found').length === 2",
        long,
        "both assets mapped",
        "document.getElementById('submit-map').textContent",
    );
    page.fill("#submit-width", "400");
    page.fill("#submit-height", "300");
    page.fill("#submit-spp", &JOB1_SPP.to_string());
    page.click("#submit-button");
    assert_eq!(page.submitted(long), 1);
    page.pick_files("#submit-scene", &[&scenes.join("spheres.toml")]);
    page.pick_files("#submit-assets", &[]);
    page.fill("#submit-width", "320");
    page.fill("#submit-height", "240");
    // Long enough to be cancelled mid-render from the jobs table: at 256 spp it ended
    // between reaching 10 % and the click in six runs of seven (2026-12-07).
    page.fill("#submit-spp", "1024");
    page.fill("#submit-priority", "-5");
    // A noise target no pixel reaches in 1024 samples: it runs as long, and its page says
    // how it may end.
    page.fill("#submit-noise_absolute", "0.0001");
    page.fill("#submit-noise_min", "128");
    page.click("#submit-button");
    assert_eq!(page.submitted(long), 2);
    // The table follows the event stream.
    page.wait(
        "document.querySelectorAll('#jobs-body tr[data-state=queued]').length === 2",
        long,
        "two queued jobs listed",
        "document.getElementById('jobs-body').innerText",
    );

    eprintln!("{:5.1} s: submitted", started.elapsed().as_secs_f64());
    // Job 1's page, joined before any worker: record each update of the canvas as it is
    // drawn, to find the mosaic of pass one among them.
    page.open("/jobs/1");
    page.wait(
        "Number(document.getElementById('live').dataset.updates || 0) >= 1",
        long,
        "the first live update",
        "document.getElementById('live-note').textContent",
    );
    page.js(
        "(() => { window.captures = []; const c = document.getElementById('live');
           new MutationObserver(() => {
             const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
             const colours = new Set(); let opaque = 0;
             for (let i = 0; i < d.length; i += 4) { colours.add((d[i] << 16) | (d[i + 1] << 8) | d[i + 2]); if (d[i + 3] === 255) opaque++; }
             const s = document.getElementById('status-line').dataset;
             captures.push({ pass: Number(s.pass), samples: Number(s.samplesDone), colours: colours.size, opaque });
           }).observe(c, { attributes: true, attributeFilter: ['data-updates'] }); })()",
    );
    let (w, h) = (400u64, 300u64);
    let w1 = worker(&grpc, &token_file);
    page.wait(
        "Number(document.getElementById('status-line').dataset.progress) > 0.15",
        long,
        "job 1 under way",
        "({...document.getElementById('status-line').dataset})",
    );
    let w2 = worker(&grpc, &token_file);

    eprintln!("{:5.1} s: workers up", started.elapsed().as_secs_f64());
    // The mosaic: an update in pass one, fewer than all pixels computed, where every pixel
    // is painted (opaque) in no more colours than pixels computed so far: blocks.
    let captures = page.js("captures");
    let captures = captures.as_array().unwrap();
    let early = captures
        .iter()
        .enumerate()
        .find(|(_, c)| {
            c["pass"] == 1 && c["colours"].as_u64().unwrap() > 1 && c["samples"].as_u64().unwrap() < w * h
        })
        .unwrap_or_else(|| panic!("no update of pass one with a partial image among {captures:?}"));
    let (i, c) = early;
    assert_eq!(c["opaque"].as_u64().unwrap(), w * h, "the early canvas has unpainted pixels: {c}");
    // Samples only grow, and the status that follows an update is at least as new as it.
    let bound = captures.get(i + 1).map_or(w * h, |n| n["samples"].as_u64().unwrap());
    let colours = c["colours"].as_u64().unwrap();
    assert!(
        colours <= bound.max(c["samples"].as_u64().unwrap()),
        "{colours} colours from {bound} samples: {c}"
    );
    assert!(colours < w * h / 4, "not a mosaic: {colours} colours in {w}x{h}");
    eprintln!("the mosaic: update {i} of {} recorded: {c}", captures.len());

    // Mid-render: pause, then a screenshot (taken before the pause, it gave a fast
    // renderer the time to finish the job first). Once the batches in flight are merged
    // the canvas is exactly the coordinator's current image.
    page.wait(
        "Number(document.getElementById('status-line').dataset.progress) > 0.25",
        long,
        "job 1 at 25 %",
        "({...document.getElementById('status-line').dataset})",
    );
    page.click("#job-pause");
    page.wait(
        "document.getElementById('job-state').dataset.state === 'paused'",
        long,
        "job 1 paused",
        "[document.getElementById('job-state').dataset.state, document.getElementById('error').innerText]",
    );
    page.screenshot("dashboard-job.png");
    let start = Instant::now();
    loop {
        let before = page.status()["samplesDone"].clone();
        let shown = page.canvas();
        let served = page.image("/api/jobs/1/image.png");
        if shown == served && page.status()["samplesDone"] == before {
            break;
        }
        assert!(
            start.elapsed() < long,
            "the paused job's canvas never matched its image ({} pixels differ)",
            if shown.2.len() == served.2.len() { differing(&shown.2, &served.2) } else { usize::MAX }
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let paused_at = page.status();
    assert!(
        paused_at["samplesDone"].as_str().unwrap().parse::<u64>().unwrap() < w * h * JOB1_SPP,
        "{paused_at}"
    );
    page.click("#job-resume");
    page.wait(
        "['running', 'done'].includes(document.getElementById('job-state').dataset.state)",
        long,
        "job 1 resumed",
        "document.getElementById('error').innerText",
    );

    eprintln!("{:5.1} s: paused and resumed", started.elapsed().as_secs_f64());
    // The end: the final flag, and the canvas is the coordinator's image exactly.
    page.wait(
        "document.getElementById('live').dataset.final === 'true' && document.getElementById('job-state').dataset.state === 'done'",
        long,
        "job 1 done on the page",
        "({...document.getElementById('status-line').dataset})",
    );
    let shown = page.canvas();
    let served = page.image("/api/jobs/1/image.png");
    assert_eq!((shown.0, shown.1), (400, 300));
    assert_eq!((served.0, served.1), (400, 300));
    assert_eq!(differing(&shown.2, &served.2), 0, "the final canvas differs from image.png");
    // Rendered (the page starts with "—"), and empty: job 1 runs to its spp.
    assert_eq!(page.js("document.getElementById('job-ends').textContent"), "", "job 1 runs to its spp");
    assert_eq!(page.js("document.getElementById('job-ends-wrap').hidden"), true);

    eprintln!("{:5.1} s: job 1 done", started.elapsed().as_secs_f64());
    // Job 2's page says how it may end.
    page.open("/jobs/2");
    page.wait(
        "document.getElementById('job-ends').textContent === 'at absolute noise 0.0001, each pixel ≥ 128 spp first' && !document.getElementById('job-ends-wrap').hidden",
        long,
        "job 2's noise target on its page",
        "document.getElementById('status-line').innerText",
    );
    // The jobs page: job 2 runs now; a screenshot, then cancel it from its row.
    page.open("/");
    page.wait(
        "document.querySelector('#jobs-body tr[data-job-id=\"2\"]')?.dataset.state === 'running' && document.querySelectorAll('#workers-body tr[data-worker-id]').length === 2",
        long,
        "job 2 running with two workers listed",
        "document.getElementById('app').innerText.slice(0, 800)",
    );
    page.wait(
        "Number(document.querySelector('#jobs-body tr[data-job-id=\"2\"] [role=progressbar]').getAttribute('aria-valuenow')) > 10",
        long,
        "job 2 at 10 %",
        "document.getElementById('jobs-body').innerText",
    );
    page.screenshot("dashboard-jobs.png");
    page.click("#jobs-body tr[data-job-id=\"2\"] button[data-action=cancel]");
    page.wait(
        "document.querySelector('#jobs-body tr[data-job-id=\"2\"]')?.dataset.state === 'cancelled'",
        long,
        "job 2 cancelled",
        "document.getElementById('error').innerText + ' | ' + document.getElementById('jobs-body').innerText",
    );

    eprintln!("{:5.1} s: job 2 cancelled", started.elapsed().as_secs_f64());
    // A viewer sees the jobs but is offered no control, and no submit form.
    page.click("#logout");
    page.wait("document.body.dataset.session === 'out'", long, "logged out", "document.body.dataset.session");
    page.fill("#login-token", VIEWER_TOKEN);
    page.click("#login-form button[type=submit]");
    page.wait(
        "document.body.dataset.session === 'in' && document.querySelectorAll('#jobs-body tr[data-job-id]').length === 2",
        long,
        "the viewer logged in",
        "document.getElementById('login-error').textContent",
    );
    assert_eq!(page.js("document.getElementById('submit-panel').hidden"), true);
    assert_eq!(
        page.js("[...document.querySelectorAll('#jobs-body button[data-action]')].filter((b) => !b.hidden).length"),
        0
    );
    drop((w1, w2));
    drop(coord);
    eprintln!("dashboard test took {:.1} s", started.elapsed().as_secs_f64());
}
