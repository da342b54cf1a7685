"""Structural checks of deploy/k8s beyond the schemas (kubernetes-validate does those).

Usage: k8s_check.py DIR. Every Deployment/StatefulSet container has CPU and memory requests
and limits; every container that declares a port has native gRPC readiness and liveness
probes on it; every Service targets pods of a workload; the kustomization lists every
manifest. Prints what it checked; exits non-zero on the first problem.
"""

import os
import sys

import yaml


def main():
    root = sys.argv[1]
    files = sorted(f for f in os.listdir(root) if f.endswith(".yaml") and f != "kustomization.yaml")
    with open(os.path.join(root, "kustomization.yaml")) as f:
        listed = yaml.safe_load(f)["resources"]
    if sorted(listed) != files:
        sys.exit(f"kustomization lists {sorted(listed)}, the folder holds {files}")
    docs = []
    for name in files:
        with open(os.path.join(root, name)) as f:
            docs += [(name, d) for d in yaml.safe_load_all(f) if d]
    workloads = {}
    for name, d in docs:
        if d["kind"] not in ("Deployment", "StatefulSet"):
            continue
        pod = d["spec"]["template"]
        workloads[d["metadata"]["name"]] = pod["metadata"]["labels"]
        for c in pod["spec"]["containers"]:
            where = f"{name}: {d['kind']} {d['metadata']['name']} container {c['name']}"
            res = c.get("resources", {})
            for part in ("requests", "limits"):
                if not {"cpu", "memory"} <= set(res.get(part, {})):
                    sys.exit(f"{where}: no cpu and memory {part}")
            for port in c.get("ports", []):
                for probe in ("readinessProbe", "livenessProbe"):
                    grpc = c.get(probe, {}).get("grpc")
                    if not grpc or grpc["port"] != port["containerPort"]:
                        sys.exit(f"{where}: no gRPC {probe} on port {port['containerPort']}")
            print(f"ok: {where}")
    for name, d in docs:
        if d["kind"] != "Service":
            continue
        sel = d["spec"]["selector"]
        if not any(all(labels.get(k) == v for k, v in sel.items()) for labels in workloads.values()):
            sys.exit(f"{name}: Service {d['metadata']['name']} selects no workload's pods")
        print(f"ok: {name}: Service {d['metadata']['name']} selects a workload")


if __name__ == "__main__":
    main()
