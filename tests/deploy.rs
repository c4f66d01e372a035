//! Offline checks of `deploy/`: the Kubernetes manifests against the schemas of a pinned
//! Kubernetes version (kubernetes-validate, strict) and the KEDA ScaledObject against
//! KEDA's CRD (tests/tools/check_deploy.py); the systemd units with `systemd-analyze`;
//! and every command line they give `tessera` parsed by this build's own `tessera`, so a
//! renamed or removed flag breaks the test. No cluster runs here.

mod common;

use std::path::Path;
use std::process::Command;

use common::{python_venv, root, run};

/// The Kubernetes versions whose schemas the manifests must pass: an older release, so
/// that they use no field that only newer clusters know (such as the grpc probe's alpha
/// `mode` of 1.37), and the newest that kubernetes-validate 1.37.0 bundles.
const KUBERNETES: [&str; 2] = ["1.34.0", "1.37.0"];

/// `args` with `$(VAR)` (Kubernetes) references replaced by what the pod would have.
fn expand_kubernetes(arg: &str) -> String {
    arg.replace("$(CPU_LIMIT)", "4")
        .replace("$(MEMORY_REQUEST)", "3221225472")
        .replace("$(POD_NAME)", "tessera-worker-0")
}

/// Whether this build's `tessera` accepts `args` (a subcommand and its flags): clap checks
/// every flag and value up to the trailing `--help`, which then ends it before anything
/// runs.
fn tessera_accepts(args: &[String]) -> Result<(), String> {
    let mut all: Vec<&str> = args.iter().map(String::as_str).collect();
    all.push("--help");
    let o = run(&all);
    if o.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&o.stderr).trim().to_string())
    }
}

#[test]
fn kubernetes_manifests_pass_the_schemas_and_name_real_flags() {
    let Some(python) = python_venv("deploy", "tests/tools/deploy-requirements.txt") else { return };
    let out = tempfile::tempdir().unwrap();
    let deploy = root().join("deploy/kubernetes");
    // What `kubectl apply -k` would send, where kubectl is at hand.
    let rendered = match Command::new("kubectl").arg("kustomize").arg(&deploy).output() {
        Ok(o) if o.status.success() => {
            let rendered = out.path().join("rendered.yaml");
            std::fs::write(&rendered, &o.stdout).unwrap();
            Some(rendered.display().to_string())
        }
        Ok(o) => panic!("kubectl kustomize {}: {}", deploy.display(), String::from_utf8_lossy(&o.stderr)),
        Err(e) => {
            eprintln!("NOTE: no kubectl ({e}): the kustomize build itself is not checked");
            None
        }
    };
    for version in KUBERNETES {
        let mut args = vec![
            root().join("tests/tools/check_deploy.py").display().to_string(),
            version.to_string(),
            deploy.display().to_string(),
            root().join("tests/tools/keda/keda.sh_scaledobjects.yaml").display().to_string(),
            out.path().display().to_string(),
        ];
        args.extend(rendered.clone());
        let o = Command::new(&python).args(&args).output().unwrap();
        let report = String::from_utf8_lossy(&o.stdout);
        eprintln!("{report}");
        assert!(
            o.status.success(),
            "check_deploy.py {version}:\n{report}\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let want = format!("StatefulSet/tessera-coordinator against Kubernetes {version} (strict)");
        assert!(report.contains(&want), "{report}");
        assert!(report.contains("ScaledObject/tessera-worker against KEDA's ScaledObject CRD"), "{report}");
    }

    let invocations: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("invocations.json")).unwrap()).unwrap();
    let invocations = invocations.as_array().unwrap();
    assert_eq!(invocations.len(), 2, "{invocations:?}");
    for inv in invocations {
        let args: Vec<String> =
            inv["args"].as_array().unwrap().iter().map(|a| expand_kubernetes(a.as_str().unwrap())).collect();
        if let Err(e) = tessera_accepts(&args) {
            panic!("{}: tessera refuses {args:?}: {e}", inv["where"]);
        }
    }

    // The templates' placeholders cannot run a farm: tessera refuses each of them.
    let secrets = out.path().join("secrets");
    let tokens = secrets.join("tessera-tokens/tokens");
    let o = run(&["coordinator", "--listen", "127.0.0.1:0", "--tokens", tokens.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("expected `ROLE NAME TOKEN`"), "{err}");
    let token = secrets.join("tessera-worker-token/token");
    let o = run(&["status", "--coordinator", "http://127.0.0.1:9", "--token-file", token.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("holds spaces"), "{err}");
    for pem in ["tessera-tls/tls.crt", "tessera-ca/ca.crt"] {
        let text = std::fs::read_to_string(secrets.join(pem)).unwrap();
        assert!(text.starts_with("<FILL:") && !text.contains("BEGIN"), "{pem} holds more than a placeholder");
    }
}

/// A unit's `ExecStart=` as words, continuation lines joined.
fn exec_start(unit: &str) -> Vec<String> {
    let joined = unit.replace("\\\n", " ");
    let line = joined.lines().find_map(|l| l.strip_prefix("ExecStart=")).expect("an ExecStart= line");
    line.split_whitespace().map(str::to_string).collect()
}

/// `systemd-analyze verify` and its security score for `unit` (a file name under
/// deploy/systemd), installed as `name` in `dir` with this build's binary.
fn verify(dir: &Path, unit: &str, name: &str) -> f64 {
    let text = std::fs::read_to_string(root().join("deploy/systemd").join(unit)).unwrap();
    let text = text.replace("/usr/local/bin/tessera", env!("CARGO_BIN_EXE_tessera"));
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    let o = Command::new("systemd-analyze").arg("verify").arg(&path).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    // verify exits 0 on unknown keys and bad values, saying so on stderr.
    assert!(o.status.success() && err.trim().is_empty(), "systemd-analyze verify {unit}:\n{err}");
    let o = Command::new("systemd-analyze").args(["security", "--offline=yes"]).arg(&path).output().unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    let score = text
        .lines()
        .find_map(|l| l.split("Overall exposure level for ").nth(1))
        .and_then(|l| l.split(": ").nth(1))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no exposure level from systemd-analyze security:\n{text}"));
    eprintln!("{unit}: systemd-analyze security exposure {score}");
    score
}

#[test]
fn systemd_units_verify_and_name_real_flags() {
    let have = Command::new("systemd-analyze").arg("--version").output();
    if !matches!(&have, Ok(o) if o.status.success()) {
        eprintln!("SKIPPED: no systemd-analyze on this machine: the units are not verified");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (unit, name) in [
        ("tessera-coordinator.service", "tessera-coordinator.service"),
        ("tessera-worker@.service", "tessera-worker@main.service"),
    ] {
        // Both measured 1.5 with systemd 252 (0 is the most confined, 10 none): above 2, a
        // hardening option was lost.
        let score = verify(dir.path(), unit, name);
        assert!(score <= 2.0, "{unit}: exposure {score}");
        let text = std::fs::read_to_string(root().join("deploy/systemd").join(unit)).unwrap();
        let words = exec_start(&text);
        assert_eq!(words[0], "/usr/local/bin/tessera", "{unit}");
        // Every credential a flag reads is loaded.
        for w in &words {
            if let Some(cred) = w.split("${CREDENTIALS_DIRECTORY}/").nth(1) {
                assert!(text.contains(&format!("LoadCredential={cred}:")), "{unit}: {cred} is not loaded");
            }
        }
        let args: Vec<String> = words[1..]
            .iter()
            .map(|w| {
                w.replace("${CREDENTIALS_DIRECTORY}", "/run/credentials/x")
                    .replace("${STATE_DIRECTORY}", "/var/lib/tessera")
                    .replace("%H", "host")
                    .replace("%i", "main")
                    .replace("$TESSERA_THREADS_ARG", "--threads=8")
            })
            .collect();
        if let Err(e) = tessera_accepts(&args) {
            panic!("{unit}: tessera refuses {args:?}: {e}");
        }
    }
}
