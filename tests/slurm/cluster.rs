//! The private Slurm cluster of `tests/slurm.rs`: its network, daemons and teardown.

use std::fs;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Why the test cannot run here, if it cannot.
pub fn missing_prerequisite() -> Option<String> {
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
pub fn run_cmd(cmd: &mut Command, limit: Duration) -> Result<String, String> {
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

pub fn ip(args: &[&str]) -> Result<String, String> {
    run_cmd(Command::new("ip").args(args), Duration::from_secs(10))
}

/// The cluster's names and addresses: a bridge `tsb<n>` on 10.216.<n>.1/24 (slurmctld and
/// the coordinator listen there), and node `i` in namespace `tss<n>-<i>` at 10.216.<n>.<i+1>.
/// `n` comes from the process id, so that two runs at once do not share a name.
pub struct Net {
    pub n: u32,
}

impl Net {
    pub fn bridge(&self) -> String {
        format!("tsb{}", self.n)
    }
    pub fn host_ip(&self) -> String {
        format!("10.216.{}.1", self.n)
    }
    pub fn ns(&self, node: u32) -> String {
        format!("tss{}-{node}", self.n)
    }
    pub fn node_ip(&self, node: u32) -> String {
        format!("10.216.{}.{}", self.n, node + 1)
    }
}

/// A daemon with its output in a log file, killed when dropped.
pub struct Daemon {
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
pub struct Cluster {
    pub net: Net,
    pub dir: PathBuf,
    tools: PathBuf,
    namespaces: Vec<String>,
    bridge: bool,
    daemons: Vec<Daemon>,
}

impl Cluster {
    /// The unpacked Slurm and MUNGE commands, with their libraries and this cluster's config.
    pub fn slurm(&self, program: &str) -> Command {
        let root = self.tools.join("root");
        let bin = ["usr/bin", "usr/sbin"].iter().map(|d| root.join(d).join(program)).find(|p| p.exists());
        let mut cmd = Command::new(bin.unwrap_or_else(|| panic!("{program} is not in {}", root.display())));
        cmd.env("LD_LIBRARY_PATH", self.library_path()).env("SLURM_CONF", self.dir.join("slurm.conf"));
        cmd
    }

    pub fn library_path(&self) -> String {
        let lib = self.tools.join("root/usr/lib/x86_64-linux-gnu");
        format!("{}:{}", lib.display(), lib.join("slurm-wlm").display())
    }

    pub fn squeue(&self, job: &str) -> String {
        run_cmd(self.slurm("squeue").args(["-h", "-j", job, "-o", "%i %t %N"]), Duration::from_secs(10))
            .unwrap_or_default()
    }

    /// Every log of the cluster, for a failure's message.
    pub fn logs(&self) -> String {
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
pub fn wait_for<T>(limit: Duration, what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

impl Cluster {
    /// A running cluster in `dir`: the network, munged, slurmctld and both slurmds, with
    /// both nodes idle. `Err` says why this host cannot have one (the test then skips);
    /// anything failing after that panics, and what was started is torn down.
    pub fn start(tools: PathBuf, dir: &Path) -> Result<Cluster, String> {
        let dir = dir.to_path_buf();
        // munged wants every directory above its socket searchable by all.
        fs::set_permissions(&dir, fs::Permissions::from_mode(0o755)).unwrap();
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
            return Err(format!("cannot make network namespaces and a bridge here ({last_error})"));
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
            return Err(format!("cannot overlay slurmstepd on /usr/sbin in a private mount namespace ({e})"));
        }

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
            let out =
                run_cmd(cluster.slurm("sinfo").args(["-h", "-N", "-o", "%N %t"]), Duration::from_secs(10))
                    .ok()?;
            let idle = out.lines().filter(|l| l.ends_with(" idle")).count();
            (idle == 2).then_some(())
        });
        Ok(cluster)
    }
}
