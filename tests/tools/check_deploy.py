#!/usr/bin/env python3
"""Offline checks of deploy/kubernetes (for tests/deploy.rs).

    check_deploy.py KUBERNETES_VERSION DEPLOY_DIR KEDA_CRD OUT_DIR [RENDERED.yaml]

- every manifest against the Kubernetes schemas of KUBERNETES_VERSION, strictly (unknown
  fields refused), with kubernetes-validate; the KEDA ScaledObject against KEDA's CRD
  (its OpenAPI schema, made strict the same way, and its one CEL rule written out here);
- kustomization.yaml lists every manifest of the directory, and nothing else;
- references hold: Secrets mounted exist, files passed to tessera lie in mounted volumes,
  probes reach the --health-listen port, Services select pods and name their ports, the
  ScaledObject's target exists;
- writes OUT_DIR/invocations.json (every `tessera` command line of the pod templates, for
  the flag check in Rust) and OUT_DIR/secrets/NAME/KEY (the templates' placeholder values,
  which tessera must refuse).
With RENDERED.yaml (the output of `kubectl kustomize`), validates that too.
Prints one `ok ...` line per check; exits 1 with `FAILED: ...` lines otherwise.
"""

import copy
import json
import os
import sys

import jsonschema
import kubernetes_validate
import yaml

failures = []


def ok(what):
    print(f"ok {what}")


def fail(what):
    failures.append(what)
    print(f"FAILED: {what}")


def strict(schema):
    """The CRD's structural schema as the API server applies it, but refusing the unknown
    fields it would silently prune (a misspelt field must be an error here)."""
    schema = copy.deepcopy(schema)

    def walk(s):
        if not isinstance(s, dict):
            return
        if s.pop("x-kubernetes-int-or-string", False):
            s.pop("type", None)
            s["anyOf"] = [{"type": "integer"}, {"type": "string"}]
        if (
            s.get("type") == "object"
            and "properties" in s
            and "additionalProperties" not in s
            and not s.get("x-kubernetes-preserve-unknown-fields")
        ):
            s["additionalProperties"] = False
        for key in ("properties", "patternProperties"):
            for sub in s.get(key, {}).values():
                walk(sub)
        for key in ("items", "additionalProperties", "not"):
            walk(s.get(key))
        for key in ("allOf", "anyOf", "oneOf"):
            for sub in s.get(key, []):
                walk(sub)

    walk(schema)
    return schema


def crd_validator(crd_path):
    with open(crd_path, encoding="utf-8") as f:
        crd = yaml.safe_load(f)
    group, kind = crd["spec"]["group"], crd["spec"]["names"]["kind"]
    schemas = {
        f"{group}/{v['name']}": strict(v["schema"]["openAPIV3Schema"])
        for v in crd["spec"]["versions"]
        if v.get("served")
    }
    return kind, schemas


def check_scaledobject(where, doc, schemas):
    schema = schemas.get(doc.get("apiVersion"))
    if schema is None:
        fail(f"{where}: apiVersion {doc.get('apiVersion')} is not served by the KEDA CRD")
        return
    errors = sorted(jsonschema.Draft7Validator(schema).iter_errors(doc), key=lambda e: list(e.path))
    for e in errors:
        fail(f"{where}: {'.'.join(map(str, e.path)) or '(root)'}: {e.message}")
    # The CRD's x-kubernetes-validations rule, which JSON Schema cannot say.
    spec = doc.get("spec", {})
    if spec.get("minReplicaCount", 0) > spec.get("maxReplicaCount", 100):
        fail(f"{where}: minReplicaCount must be less than or equal to maxReplicaCount")
    if not errors:
        ok(f"{where} against KEDA's ScaledObject CRD ({doc['apiVersion']})")


def check_resource(where, doc, version):
    try:
        kubernetes_validate.validate(doc, version, strict=True)
        ok(f"{where} against Kubernetes {version} (strict)")
    except kubernetes_validate.ValidationError as e:
        path = ".".join(map(str, e.path)) or "(root)"
        fail(f"{where}: {path}: {e.message}")
    except kubernetes_validate.SchemaNotFoundError:
        fail(f"{where}: no Kubernetes {version} schema for {doc.get('apiVersion')} {doc.get('kind')}")


def documents(path):
    with open(path, encoding="utf-8") as f:
        return [d for d in yaml.safe_load_all(f) if d is not None]


def validate(path, docs, version, crd_kind, crd_schemas):
    for doc in docs:
        where = f"{os.path.basename(path)}: {doc.get('kind')}/{doc.get('metadata', {}).get('name')}"
        if doc.get("kind") == crd_kind and doc.get("apiVersion", "").startswith("keda.sh/"):
            check_scaledobject(where, doc, crd_schemas)
        else:
            check_resource(where, doc, version)


def pod_templates(resources):
    for doc in resources:
        if doc.get("kind") in ("StatefulSet", "Deployment"):
            yield doc, doc["spec"]["template"]


def check_references(resources, out_dir):
    by_kind = {}
    for doc in resources:
        by_kind.setdefault(doc["kind"], {})[doc["metadata"]["name"]] = doc
    secrets = by_kind.get("Secret", {})
    invocations = []
    for owner, template in pod_templates(resources):
        name = owner["metadata"]["name"]
        spec = template["spec"]
        volumes = {v["name"]: v for v in spec.get("volumes", [])}
        for v in volumes.values():
            if "secret" in v and v["secret"]["secretName"] not in secrets:
                fail(f"{name}: volume {v['name']} mounts Secret {v['secret']['secretName']}, not defined")
        for claim in owner["spec"].get("volumeClaimTemplates", []):
            volumes[claim["metadata"]["name"]] = claim
        for c in spec["containers"]:
            where = f"{name}/{c['name']}"
            mounts = [m["mountPath"].rstrip("/") + "/" for m in c.get("volumeMounts", [])]
            for m in c.get("volumeMounts", []):
                if m["name"] not in volumes:
                    fail(f"{where}: mounts volume {m['name']}, not defined")
            args = c.get("args", [])
            flags = dict(a[2:].split("=", 1) for a in args if a.startswith("--") and "=" in a)
            for flag in ("data", "tokens", "tls-cert", "tls-key", "ca", "token-file"):
                if flag in flags:
                    path = flags[flag].rstrip("/") + "/"
                    if not any(path.startswith(m) for m in mounts):
                        fail(f"{where}: --{flag}={flags[flag]} is in no mounted volume")
            if "health-listen" in flags:
                port = int(flags["health-listen"].rsplit(":", 1)[1])
                for probe in ("readinessProbe", "livenessProbe", "startupProbe"):
                    grpc = c.get(probe, {}).get("grpc")
                    if grpc is None:
                        fail(f"{where}: {probe} is not a grpc probe")
                    elif grpc["port"] != port:
                        fail(f"{where}: {probe} asks port {grpc['port']}, --health-listen is {port}")
            ports = {p["name"] for p in c.get("ports", [])}
            for svc in by_kind.get("Service", {}).values():
                selector = svc["spec"].get("selector", {})
                labels = template["metadata"].get("labels", {})
                if selector and all(labels.get(k) == v for k, v in selector.items()):
                    for p in svc["spec"]["ports"]:
                        if isinstance(p["targetPort"], str) and p["targetPort"] not in ports:
                            fail(f"Service {svc['metadata']['name']}: targetPort {p['targetPort']} not in {where}")
            env = {e["name"]: e for e in c.get("env", [])}
            for a in args:
                start = a.find("$(")
                if start >= 0 and a[start + 2 : a.index(")", start)] not in env:
                    fail(f"{where}: {a} names an environment variable the container does not set")
            invocations.append({"where": f"{name}/{c['name']}", "args": args})
    for so in by_kind.get("ScaledObject", {}).values():
        target = so["spec"]["scaleTargetRef"]
        if target.get("kind", "Deployment") != "Deployment" or target["name"] not in by_kind.get("Deployment", {}):
            fail(f"ScaledObject {so['metadata']['name']}: scales {target}, not a Deployment here")
    if not failures:
        ok(f"references between {len(resources)} resources")
    with open(os.path.join(out_dir, "invocations.json"), "w", encoding="utf-8") as f:
        json.dump(invocations, f, indent=1)
    for name, secret in secrets.items():
        os.makedirs(os.path.join(out_dir, "secrets", name), exist_ok=True)
        for key, value in secret.get("stringData", {}).items():
            path = os.path.join(out_dir, "secrets", name, key)
            with open(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "w") as f:
                f.write(value)


def main():
    if len(sys.argv) not in (5, 6):
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    version, deploy_dir, crd_path, out_dir = sys.argv[1:5]
    crd_kind, crd_schemas = crd_validator(crd_path)
    manifests = sorted(f for f in os.listdir(deploy_dir) if f.endswith((".yaml", ".yml")))
    kustomization = documents(os.path.join(deploy_dir, "kustomization.yaml"))[0]
    listed = sorted(kustomization.get("resources", []))
    others = [f for f in manifests if f != "kustomization.yaml"]
    if listed != others:
        fail(f"kustomization.yaml lists {listed}, the directory holds {others}")
    else:
        ok(f"kustomization.yaml lists the {len(others)} manifests")
    resources = []
    for f in others:
        path = os.path.join(deploy_dir, f)
        docs = documents(path)
        validate(path, docs, version, crd_kind, crd_schemas)
        resources.extend(docs)
    check_references(resources, out_dir)
    if len(sys.argv) == 6:
        validate(sys.argv[5], documents(sys.argv[5]), version, crd_kind, crd_schemas)
    if failures:
        sys.exit(1)


if __name__ == "__main__":
    main()
