//! Workers from Slurm, end to end: a private Slurm cluster from Debian's packages (unpacked
//! by `scripts/slurm/fetch.sh`, no system install) — munged and slurmctld on this host, two
//! compute nodes `node1` and `node2`, each slurmd in its own network namespace behind a
//! veth on a private bridge. `deploy/slurm/tessera-workers.sbatch` is submitted as a
//! two-task array; its workers reach a TLS coordinator with tokens over the veths. A job is
//! submitted, one node's array task is cancelled with `scancel` mid-render, and the image
//! must be byte-identical to a local render. The cancelled worker must have left cleanly:
//! it ended its stream on SIGTERM (the coordinator logs `worker left (closed)`, where a
//! killed process shows `(lost)`) and its batches were taken back at once.
//!
//! Needs root, iproute2, nsenter/unshare, overlayfs and Debian's apt; where any is missing
//! the test prints `SKIPPED: <why>` and passes.

mod common;

use common::*;
use std::fs;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The scene, its settings, and how far the job must be when one worker is cancelled.
const SCENE: &str = "scenes/showcase.toml";
const SETTINGS: [&str; 4] = ["--size", "160x120", "--spp", "48"];
/// The coordinator's silence timeout: far longer than the test waits for the leave, so the
/// batches cannot have come back by expiry.
const WORKER_TIMEOUT_S: u64 = 60;
/// How soon after `scancel` the coordinator must have taken the worker's batches back.
const LEAVE_BOUND: Duration = Duration::from_secs(10);

/// Why the test cannot run here, if it cannot.
fn missing_prerequisite() -> Option<String> {
    let uid = Command::new("id")
        .arg("-u")
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string());
    if uid.as_deref() != Some("0") {
        return Some("not root: network namespaces, mounts and slurmd need root".into());
    }
    for tool in ["ip", "nsenter", "unshare", "apt-get", "dpkg-deb"] {
        if Command::new("sh")
            .args(["-c", &format!("command -v {tool}")])
            .output()
            .map_or(true, |o| !o.status.success())
        {
            return Some(format!("{tool} not found"));
        }
    }
    None
}

/// Runs a command to completion within `limit`; its stdout, or why it failed.
fn run_cmd(cmd: &mut Command, limit: Duration) -> Result<String, String> {
    let what = format!("{cmd:?}");
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("{what}: {e}"))?;
    let start = Instant::now();
    while child.try_wait().map_err(|e| e.to_string())?.is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("{what} took longer than {limit:?}"));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().map_err(|e| e.to_string())?;
    if out.status.success() {
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    } else {
        Err(format!("{what}: {}; {}", out.status, String::from_utf8_lossy(&out.stderr).trim()))
    }
}

fn ip(args: &[&str]) -> Result<String, String> {
    run_cmd(Command::new("ip").args(args), Duration::from_secs(10))
}

/// The cluster's names and addresses: a bridge `tsb<n>` on 10.216.<n>.1/24 (slurmctld and
/// the coordinator listen there), and node `i` in namespace `tss<n>-<i>` at 10.216.<n>.<i+1>.
/// `n` comes from the process id, so that two runs at once do not share a name.
struct Net {
    n: u32,
}

impl Net {
    fn bridge(&self) -> String {
        format!("tsb{}", self.n)
    }
    fn host_ip(&self) -> String {
        format!("10.216.{}.1", self.n)
    }
    fn ns(&self, node: u32) -> String {
        format!("tss{}-{node}", self.n)
    }
    fn node_ip(&self, node: u32) -> String {
        format!("10.216.{}.{}", self.n, node + 1)
    }
}

/// A daemon with its output in a log file, killed when dropped.
struct Daemon {
    child: Child,
}

impl Daemon {
    fn spawn(cmd: &mut Command, log: &Path) -> Daemon {
        let out = fs::File::create(log).unwrap();
        let err = out.try_clone().unwrap();
        let child = cmd.stdin(Stdio::null()).stdout(out).stderr(err).spawn().unwrap();
        Daemon { child }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Everything the test started, torn down when dropped, also on a failed assertion: jobs
/// cancelled, every process in the nodes' namespaces killed (slurmstepd and the workers
/// are not slurmd's children for long), the daemons, the namespaces and the bridge.
struct Cluster {
    net: Net,
    dir: PathBuf,
    tools: PathBuf,
    namespaces: Vec<String>,
    bridge: bool,
    daemons: Vec<Daemon>,
}

impl Cluster {
    /// The unpacked Slurm and MUNGE commands, with their libraries and this cluster's config.
    fn slurm(&self, program: &str) -> Command {
        let root = self.tools.join("root");
        let bin = ["usr/bin", "usr/sbin"].iter().map(|d| root.join(d).join(program)).find(|p| p.exists());
        let mut cmd = Command::new(bin.unwrap_or_else(|| panic!("{program} is not in {}", root.display())));
        cmd.env("LD_LIBRARY_PATH", self.library_path()).env("SLURM_CONF", self.dir.join("slurm.conf"));
        cmd
    }

    fn library_path(&self) -> String {
        let lib = self.tools.join("root/usr/lib/x86_64-linux-gnu");
        format!("{}:{}", lib.display(), lib.join("slurm-wlm").display())
    }

    fn squeue(&self, job: &str) -> String {
        run_cmd(self.slurm("squeue").args(["-h", "-j", job, "-o", "%i %t %N"]), Duration::from_secs(10))
            .unwrap_or_default()
    }

    /// Every log of the cluster, for a failure's message.
    fn logs(&self) -> String {
        let mut all = String::new();
        let Ok(entries) = fs::read_dir(self.dir.join("log")) else { return all };
        let mut paths: Vec<_> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        paths.sort();
        for p in paths {
            let text = fs::read_to_string(&p).unwrap_or_default();
            let tail: Vec<&str> = text.lines().rev().take(25).collect();
            all.push_str(&format!("--- {} (last lines)\n", p.display()));
            for l in tail.into_iter().rev() {
                all.push_str(l);
                all.push('\n');
            }
        }
        all
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("{}", self.logs());
        }
        // Jobs first, so that slurmd does not restart them; then whatever is left.
        let _ = run_cmd(self.slurm("scancel").args(["--user", "root"]), Duration::from_secs(5));
        for ns in &self.namespaces {
            if let Ok(pids) = ip(&["netns", "pids", ns]) {
                for pid in pids.split_whitespace() {
                    let _ = Command::new("kill").args(["-9", pid]).stderr(Stdio::null()).status();
                }
            }
        }
        self.daemons.clear();
        for ns in &self.namespaces {
            let _ = ip(&["netns", "del", ns]);
        }
        if self.bridge {
            let _ = ip(&["link", "del", &self.net.bridge()]);
        }
    }
}

/// The bridge and the two nodes' namespaces; an error if this host cannot make them.
fn make_network(cluster: &mut Cluster) -> Result<(), String> {
    let (bridge, host) = (cluster.net.bridge(), cluster.net.host_ip());
    ip(&["link", "add", &bridge, "type", "bridge"])?;
    cluster.bridge = true;
    ip(&["addr", "add", &format!("{host}/24"), "dev", &bridge])?;
    ip(&["link", "set", &bridge, "up"])?;
    for node in [1, 2] {
        let ns = cluster.net.ns(node);
        ip(&["netns", "add", &ns])?;
        cluster.namespaces.push(ns.clone());
        ip(&["-n", &ns, "link", "set", "lo", "up"])?;
        let veth = format!("{ns}v");
        ip(&["link", "add", &veth, "type", "veth", "peer", "name", "eth0", "netns", &ns])?;
        ip(&["link", "set", &veth, "master", &bridge, "up"])?;
        ip(&["-n", &ns, "addr", "add", &format!("{}/24", cluster.net.node_ip(node)), "dev", "eth0"])?;
        ip(&["-n", &ns, "link", "set", "eth0", "up"])?;
    }
    Ok(())
}

/// A port free on this host a moment ago (for slurmctld, which takes a fixed one).
fn free_port() -> u16 {
    std::net::TcpListener::bind("0.0.0.0:0").unwrap().local_addr().unwrap().port()
}

fn slurm_conf(cluster: &Cluster, ctld_port: u16) -> String {
    let d = cluster.dir.display();
    let host = String::from_utf8(Command::new("hostname").arg("-s").output().unwrap().stdout).unwrap();
    let nodes: String = [1, 2]
        .iter()
        .map(|&i| {
            format!(
                "NodeName=node{i} NodeAddr={} CPUs=1 RealMemory=2048 State=UNKNOWN\n",
                cluster.net.node_ip(i)
            )
        })
        .collect();
    format!(
        "# A private cluster for tests/slurm.rs: every path under {d}, its own ports.\n\
         ClusterName=tessera-test\n\
         SlurmctldHost={host}({hostip})\n\
         SlurmctldPort={ctld_port}\n\
         SlurmdPort=6818\n\
         SlurmUser=root\n\
         SlurmdUser=root\n\
         AuthType=auth/munge\n\
         CredType=cred/munge\n\
         AuthInfo=socket={d}/munge-run/munge.socket\n\
         StateSaveLocation={d}/ctld\n\
         SlurmdSpoolDir={d}/spool/%n\n\
         SlurmctldPidFile={d}/ctld/slurmctld.pid\n\
         SlurmdPidFile={d}/spool/%n/slurmd.pid\n\
         SlurmctldLogFile={d}/log/slurmctld.log\n\
         SlurmdLogFile={d}/log/slurmd-%n.log\n\
         PluginDir={plugins}\n\
         MailProg=/bin/true\n\
         ProctrackType=proctrack/linuxproc\n\
         TaskPlugin=task/none\n\
         JobAcctGatherType=jobacct_gather/none\n\
         AccountingStorageType=accounting_storage/none\n\
         JobCompType=jobcomp/none\n\
         SwitchType=switch/none\n\
         MpiDefault=none\n\
         SchedulerType=sched/backfill\n\
         SelectType=select/cons_tres\n\
         SelectTypeParameters=CR_CPU_Memory\n\
         ReturnToService=2\n\
         KillWait=5\n\
         {nodes}\
         PartitionName=render Nodes=node1,node2 Default=YES MaxTime=INFINITE State=UP\n",
        host = host.trim(),
        hostip = cluster.net.host_ip(),
        plugins = cluster.tools.join("root/usr/lib/x86_64-linux-gnu/slurm-wlm").display(),
    )
}

/// Polls `f` until it returns `Some`, at most `limit`; panics with `what` after that.
fn wait_for<T>(limit: Duration, what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The value of `key=value` in a log line.
fn field<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    line.split_whitespace().find_map(|w| w.strip_prefix(key)?.strip_prefix('='))
}

/// A secret of 32 hex digits from the OS.
fn secret() -> String {
    let mut bytes = [0u8; 16];
    use std::io::Read;
    fs::File::open("/dev/urandom").unwrap().read_exact(&mut bytes).unwrap();
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn write_private(path: &Path, text: &str) {
    fs::write(path, text).unwrap();
    fs::set_permissions(path, fs::Permissions::from_mode(0o600)).unwrap();
}

#[test]
fn slurm_workers_render_the_same_image_when_one_is_cancelled() {
    let started = Instant::now();
    if let Some(why) = missing_prerequisite() {
        eprintln!("SKIPPED: {why}");
        return;
    }
    // The cache sits beside the binary under test: target/tools/slurm.
    let target = Path::new(env!("CARGO_BIN_EXE_tessera")).parent().unwrap().parent().unwrap().to_path_buf();
    let tools = target.join("tools/slurm");
    let fetch = root().join("scripts/slurm/fetch.sh");
    if let Err(e) = run_cmd(Command::new(&fetch).arg(&tools), Duration::from_secs(300)) {
        eprintln!("SKIPPED: cannot get Debian's Slurm and MUNGE packages: {e}");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    // munged wants every directory above its socket searchable by all.
    fs::set_permissions(tmp.path(), fs::Permissions::from_mode(0o755)).unwrap();
    let dir = tmp.path().to_path_buf();
    for d in ["log", "ctld", "spool/node1", "spool/node2", "munge", "munge-run", "pki", "tokens"] {
        fs::create_dir_all(dir.join(d)).unwrap();
    }
    fs::set_permissions(dir.join("munge"), fs::Permissions::from_mode(0o700)).unwrap();
    fs::set_permissions(dir.join("munge-run"), fs::Permissions::from_mode(0o755)).unwrap();
    // A bridge and namespaces of this run's own; another name if one is taken.
    let mut last_error = String::new();
    let mut made = None;
    for attempt in 0..5 {
        let mut cluster = Cluster {
            net: Net { n: 20 + (std::process::id() + attempt * 37) % 200 },
            dir: dir.clone(),
            tools: tools.clone(),
            namespaces: vec![],
            bridge: false,
            daemons: vec![],
        };
        match make_network(&mut cluster) {
            Ok(()) => {
                made = Some(cluster);
                break;
            }
            Err(e) => last_error = e,
        }
    }
    let Some(mut cluster) = made else {
        eprintln!("SKIPPED: cannot make network namespaces and a bridge here ({last_error})");
        return;
    };
    let overlay = format!("lowerdir={}:/usr/sbin", tools.join("sbin").display());
    let probe = run_cmd(
        Command::new("unshare").args([
            "--mount",
            "--propagation",
            "private",
            "mount",
            "-t",
            "overlay",
            "overlay",
            "-o",
            &overlay,
            "/usr/sbin",
        ]),
        Duration::from_secs(10),
    );
    if let Err(e) = probe {
        eprintln!("SKIPPED: cannot overlay slurmstepd on /usr/sbin in a private mount namespace ({e})");
        return;
    }

    // The reference, rendered here by two local workers.
    let scene = root().join(SCENE);
    let reference = dir.join("reference.png");
    render_local(&scene, &reference, 2, &SETTINGS);
    let reference_done = started.elapsed();

    // MUNGE: a key, and a socket of this cluster's own that Slurm is pointed at.
    let key = dir.join("munge/munge.key");
    run_cmd(cluster.slurm("mungekey").args(["--create", "--keyfile"]).arg(&key), Duration::from_secs(10))
        .unwrap();
    let socket = dir.join("munge-run/munge.socket");
    let mut munged = cluster.slurm("munged");
    munged.arg("-F").arg("--key-file").arg(&key).arg("--socket").arg(&socket);
    munged
        .arg("--pid-file")
        .arg(dir.join("munge/munged.pid"))
        .arg("--seed-file")
        .arg(dir.join("munge/munged.seed"));
    cluster.daemons.push(Daemon::spawn(&mut munged, &dir.join("log/munged.log")));
    wait_for(Duration::from_secs(10), "munged's socket", || socket.exists().then_some(()));

    let ctld_port = free_port();
    fs::write(dir.join("slurm.conf"), slurm_conf(&cluster, ctld_port)).unwrap();
    let conf = dir.join("slurm.conf");
    let mut ctld = cluster.slurm("slurmctld");
    ctld.arg("-D").arg("-f").arg(&conf);
    cluster.daemons.push(Daemon::spawn(&mut ctld, &dir.join("log/slurmctld.out")));
    // Each slurmd in its node's network namespace, entered with nsenter (`ip netns exec`
    // would remount /sys and break slurmd's cgroup probe), and in a private mount
    // namespace where slurmstepd appears at the path compiled into slurmd.
    for node in [1, 2] {
        let slurmd = tools.join("root/usr/sbin/slurmd");
        let script = format!(
            "mount -t overlay overlay -o {overlay} /usr/sbin && exec {} -D -N node{node} -f {}",
            slurmd.display(),
            conf.display()
        );
        let mut cmd = Command::new("nsenter");
        cmd.arg(format!("--net=/run/netns/{}", cluster.net.ns(node)));
        cmd.args(["unshare", "--mount", "--propagation", "private", "sh", "-c", &script]);
        cmd.env("LD_LIBRARY_PATH", cluster.library_path());
        cluster.daemons.push(Daemon::spawn(&mut cmd, &dir.join(format!("log/slurmd-node{node}.out"))));
    }
    wait_for(Duration::from_secs(40), "both nodes idle in sinfo", || {
        let out = run_cmd(cluster.slurm("sinfo").args(["-h", "-N", "-o", "%N %t"]), Duration::from_secs(10))
            .ok()?;
        let idle = out.lines().filter(|l| l.ends_with(" idle")).count();
        (idle == 2).then_some(())
    });
    let cluster_up = started.elapsed();

    // The coordinator: TLS on the bridge, a token per node and one for the submitter.
    let pki = dir.join("pki");
    let host = cluster.net.host_ip();
    for args in [vec!["certs", "ca", "--dir"], vec!["certs", "server", "--host", &host, "--dir"]] {
        let mut a = args.clone();
        a.push(pki.to_str().unwrap());
        let o = run(&a);
        assert!(o.status.success(), "tessera {a:?}: {}", String::from_utf8_lossy(&o.stderr));
    }
    let (submitter, node_tokens) = (secret(), [secret(), secret()]);
    let tokens = dir.join("tokens/all");
    write_private(
        &tokens,
        &format!(
            "admin tester {submitter}\nworker node1 {}\nworker node2 {}\n",
            node_tokens[0], node_tokens[1]
        ),
    );
    write_private(&dir.join("tokens/tester.token"), &submitter);
    for (i, t) in node_tokens.iter().enumerate() {
        write_private(&dir.join(format!("tokens/node{}.token", i + 1)), t);
    }
    let pki_s = pki.display().to_string();
    let timeout = WORKER_TIMEOUT_S.to_string();
    let coordinator = Proc::spawn_with_env(
        &[
            "coordinator",
            "--listen",
            &format!("{host}:0"),
            "--tls-cert",
            &format!("{pki_s}/server.pem"),
            "--tls-key",
            &format!("{pki_s}/server.key"),
            "--tokens",
            tokens.to_str().unwrap(),
            "--worker-timeout",
            &timeout,
        ],
        &[("NO_COLOR", "1")],
    );
    let line = coordinator.wait_for("coordinator listening on ", Duration::from_secs(30));
    let addr = line.rsplit("listening on ").next().unwrap().split_whitespace().next().unwrap().to_string();
    let url = format!("https://{addr}");
    let ca = format!("{pki_s}/ca.pem");
    let tester_token = dir.join("tokens/tester.token").display().to_string();
    let client = ["--coordinator", url.as_str(), "--ca", ca.as_str(), "--token-file", tester_token.as_str()];

    // The worker array, exactly as a user submits it.
    let recipe = root().join("deploy/slurm/tessera-workers.sbatch");
    let submitted = run_cmd(
        cluster
            .slurm("sbatch")
            .arg("--parsable")
            .arg("--array=0-1")
            .arg(format!("--output={}/log/worker-%A_%a.log", dir.display()))
            .arg(format!("--chdir={}", dir.display()))
            .arg(&recipe)
            .env("TESSERA_COORDINATOR", &url)
            .env("TESSERA_CA", &ca)
            .env("TESSERA_TOKEN_FILE", format!("{}/tokens/{{node}}.token", dir.display()))
            .env("TESSERA_BIN", env!("CARGO_BIN_EXE_tessera"))
            .env("RUST_LOG", "info")
            .env("NO_COLOR", "1"),
        Duration::from_secs(20),
    )
    .unwrap();
    let array = submitted.trim().split(';').next().unwrap().to_string();
    assert!(array.parse::<u64>().is_ok(), "sbatch --parsable printed {submitted:?}");
    // Both workers joined, one per node, named after the node and the array index.
    wait_for(Duration::from_secs(40), "two workers from the array joining", || {
        let log = coordinator.stderr.lock().unwrap().clone();
        let joined = log.lines().filter(|l| l.contains("worker joined")).count();
        (joined >= 2).then_some(())
    });
    let queue = cluster.squeue(&array);
    let on_node2 = queue
        .lines()
        .find(|l| l.ends_with(" node2"))
        .unwrap_or_else(|| panic!("no array task on node2: {queue:?}"))
        .split_whitespace()
        .next()
        .unwrap()
        .to_string();
    let index = on_node2.rsplit('_').next().unwrap().to_string();
    let name = format!("node2-{array}_{index}");
    let log = coordinator.stderr.lock().unwrap().clone();
    let joined = log
        .lines()
        .find(|l| l.contains("worker joined") && field(l, "name") == Some(name.as_str()))
        .unwrap_or_else(|| panic!("no worker named {name} joined:\n{log}"));
    // `worker=worker 2 name=…`: the id's display has a space in it.
    let id = joined.split("worker=").nth(1).and_then(|r| r.split(" name=").next()).unwrap().to_string();
    assert!(log.contains("name=node1-"), "no worker from node1 joined:\n{log}");

    // The job, then node2's worker cancelled mid-render.
    let out = dir.join("farm.png");
    let mut submit_args = vec!["submit", scene.to_str().unwrap(), "-o", out.to_str().unwrap()];
    submit_args.extend_from_slice(&client);
    submit_args.extend_from_slice(&SETTINGS);
    let mut submit = Proc::spawn(&submit_args);
    let mut status_args = vec!["status"];
    status_args.extend_from_slice(&client);
    let at_cancel = wait_for(Duration::from_secs(60), "the job passing 15 %", || {
        let o = run(&status_args);
        let p = job_percent(&String::from_utf8_lossy(&o.stdout), 1);
        (p > 15.0).then_some(p)
    });
    assert!(at_cancel < 75.0, "the job went too fast to cancel a worker mid-render ({at_cancel}%)");
    let cancelled_at = Instant::now();
    run_cmd(cluster.slurm("scancel").arg(&on_node2), Duration::from_secs(10)).unwrap();
    // The worker left cleanly: it ended its stream ("closed", not a lost connection), and
    // the coordinator took its batches back at once, not after its silence timeout.
    let left = wait_for(LEAVE_BOUND, "the cancelled worker leaving", || {
        let log = coordinator.stderr.lock().unwrap().clone();
        log.lines()
            .find(|l| l.contains("worker left") && l.contains(&format!("worker={id} ")))
            .map(str::to_string)
    });
    let leave_time = cancelled_at.elapsed();
    assert!(left.contains("worker left (closed)"), "the worker did not leave cleanly: {left}");
    assert!(taken_back(&left) >= 1, "the cancelled worker held no batches mid-render: {left}");
    let worker_log = dir.join(format!("log/worker-{array}_{index}.log"));
    wait_for(Duration::from_secs(10), "the cancelled task leaving the queue", || {
        (!cluster.squeue(&array).contains(&on_node2)).then_some(())
    });
    let text = fs::read_to_string(&worker_log).unwrap_or_default();
    assert!(text.contains("stopping: ending the work stream"), "the worker did not stop on SIGTERM:\n{text}");
    let remaining = cluster.squeue(&array);
    assert!(remaining.contains(" R node1"), "node1's worker should still run: {remaining:?}");

    let status = submit.wait(Duration::from_secs(90));
    assert!(status.success(), "tessera submit failed:\n{}", submit.stderr.lock().unwrap());
    assert_eq!(read(&out), read(&reference), "the Slurm farm's image differs from the local render");
    eprintln!(
        "slurm test: reference {:.1}s, cluster up at {:.1}s, cancelled at {at_cancel:.0}%, \
         worker gone {:.2}s after scancel ({left}), total {:.1}s",
        reference_done.as_secs_f64(),
        cluster_up.as_secs_f64(),
        leave_time.as_secs_f64(),
        started.elapsed().as_secs_f64()
    );
    drop(coordinator);
    drop(cluster);
}

/// The number in `batches_taken_back=N` of a `worker left` line.
fn taken_back(line: &str) -> u64 {
    field(line, "batches_taken_back").and_then(|n| n.parse().ok()).unwrap_or(0)
}

/// What scancel relies on, without Slurm: SIGTERM makes a worker end its stream, the
/// coordinator take its leases back at once, and the process exit 0.
#[test]
fn a_worker_leaves_cleanly_on_sigterm() {
    let coord = Coordinator::start_at("127.0.0.1:0", &["--worker-timeout", "60"], &[("NO_COLOR", "1")]);
    let mut worker = coord.worker(1);
    let scene = root().join(SCENE);
    let mut submit = vec!["submit", scene.to_str().unwrap(), "--coordinator", coord.url.as_str()];
    submit.extend_from_slice(&SETTINGS);
    let o = run(&submit);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    coord.wait_until(1, Duration::from_secs(30), "the job rendering", |s| s.samples_done > 0);
    let sent = Instant::now();
    worker.signal(15);
    let status = worker.wait(Duration::from_secs(5));
    assert!(status.success(), "the worker exited with {status} on SIGTERM");
    let left = coord.proc.wait_for("worker left", Duration::from_secs(5));
    assert!(left.contains("worker left (closed)"), "not a clean leave: {left}");
    assert!(taken_back(&left) >= 1, "the worker held no batches when it left: {left}");
    assert!(sent.elapsed() < Duration::from_secs(5), "leaving took {:?}", sent.elapsed());
    assert!(worker.stderr.lock().unwrap().contains("stopping: ending the work stream"));
}
