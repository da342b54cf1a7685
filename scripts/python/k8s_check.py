"""Structural checks of deploy/k8s beyond the schemas (kubernetes-validate does those).

Usage: k8s_check.py DIR. Prints what it checked; exits non-zero on the first problem.

- Workloads: every Deployment/StatefulSet container has CPU and memory requests and limits,
  and every port it declares has a readiness and a liveness probe on it (native gRPC, or, for
  a TLS deployment, an exec probe running `jsae health --addr ...:PORT`).
- Services target pods of a workload; the kustomization lists every manifest.
- The token: the kustomization's secretGenerator makes it from files (no literals, and no
  Secret manifest, which would put the token in git); a file that exists must hold a token,
  and inside a git work tree it must be ignored; the file need not exist (the user creates
  it). Every container mounts that Secret, readable by the pod's user, and sets
  JSAE_AUTH_TOKEN_FILE to the mounted file.
- NetworkPolicies: a default-deny ingress policy; every selector selects some workload; every
  declared port and the metrics port (the ConfigMap's JSAE_METRICS_LISTEN) of every workload
  is admitted by a policy, whose sources are printed; and every service URL in a container's
  arguments (`http://jsae-learner:50052`) is reachable from that container's pods.
- In step with the swarm stack (DIR/../docker-stack.yml) and its settings (DIR/../config.toml):
  the actor Deployment (the one whose container runs `actor`) spreads its pods over nodes (a
  podAntiAffinity or topologySpreadConstraints on kubernetes.io/hostname whose selector matches
  the actor pods' labels) and has as many replicas as the stack's default actor count (the N
  of services.actor.deploy.replicas `${JSAE_ACTORS:-N}`); every ConfigMap `config.toml` holds
  the same settings as deploy/config.toml.
"""

import os
import posixpath
import re
import subprocess
import sys
import tomllib

import yaml

TOKEN_ENV = "JSAE_AUTH_TOKEN_FILE"
MIN_TOKEN_CHARS = 16
URL = re.compile(r"https?://([A-Za-z0-9.-]+):(\d+)")
HOSTNAME = "kubernetes.io/hostname"
# a compose/stack variable with a default: ${NAME:-N} (or ${NAME-N})
STACK_DEFAULT = re.compile(r"^\$\{\w+:?-(\d+)\}$")


def main():
    root = sys.argv[1]
    files = sorted(f for f in os.listdir(root) if f.endswith(".yaml") and f != "kustomization.yaml")
    with open(os.path.join(root, "kustomization.yaml")) as f:
        kustomization = yaml.safe_load(f)
    listed = kustomization["resources"]
    if sorted(listed) != files:
        sys.exit(f"kustomization lists {sorted(listed)}, the folder holds {files}")
    docs = []
    for name in files:
        with open(os.path.join(root, name)) as f:
            docs += [(name, d) for d in yaml.safe_load_all(f) if d]
    for name, d in docs:
        if d["kind"] == "Secret":
            sys.exit(f"{name}: Secret {d['metadata']['name']}: a manifest would put the token in "
                     "git; generate it (kustomization secretGenerator)")
    secrets = generated_secrets(root, kustomization)
    workloads = check_workloads(docs, secrets)
    check_services(docs, workloads)
    check_network_policies(docs, workloads)
    actor = actor_deployment(docs)
    check_actor_spread(*actor)
    check_actor_replicas(root, *actor)
    check_settings(root, docs)


def generated_secrets(root, kustomization):
    """The secretGenerator's Secrets as {(namespace, name): {key: file}}, each file checked."""
    secrets = {}
    for gen in kustomization.get("secretGenerator", []):
        where = f"kustomization: secretGenerator {gen['name']}"
        if gen.get("literals") or gen.get("envs"):
            sys.exit(f"{where}: literals or envs would put the token in git; use files")
        keys = {}
        for entry in gen.get("files", []):
            key, _, path = entry.rpartition("=")
            keys[key or posixpath.basename(path)] = path
            check_token_file(root, where, path)
        secrets[(gen.get("namespace"), gen["name"])] = keys
    return secrets


def check_token_file(root, where, path):
    """A token file that exists holds one token; inside a git work tree it is ignored."""
    full = os.path.join(root, path)
    try:
        ignored = subprocess.run(["git", "-C", root, "check-ignore", "-q", path],
                                 capture_output=True).returncode
    except FileNotFoundError:
        ignored = None  # no git: nothing to commit it to
    if ignored == 1:
        sys.exit(f"{where}: {full} is not git-ignored: the token would be committed")
    if not os.path.exists(full):
        print(f"ok: {where}: {path} not created yet (kubectl apply -k needs it; git ignores it)")
        return
    with open(full, "rb") as f:
        token = f.read().strip()
    if len(token) < MIN_TOKEN_CHARS or not all(0x21 <= b <= 0x7E for b in token):
        sys.exit(f"{where}: {full} is not one line of at least {MIN_TOKEN_CHARS} visible "
                 "ASCII characters")
    print(f"ok: {where}: {path} holds a token")


def check_workloads(docs, secrets):
    """Resources, probes and the mounted token of every container; {name: (doc, labels)}."""
    workloads = {}
    for name, d in docs:
        if d["kind"] not in ("Deployment", "StatefulSet"):
            continue
        pod = d["spec"]["template"]
        workloads[d["metadata"]["name"]] = (d, pod["metadata"]["labels"])
        for c in pod["spec"]["containers"]:
            where = f"{name}: {d['kind']} {d['metadata']['name']} container {c['name']}"
            res = c.get("resources", {})
            for part in ("requests", "limits"):
                if not {"cpu", "memory"} <= set(res.get(part, {})):
                    sys.exit(f"{where}: no cpu and memory {part}")
            for port in c.get("ports", []):
                for probe in ("readinessProbe", "livenessProbe"):
                    if not probes(c.get(probe, {}), port["containerPort"]):
                        sys.exit(f"{where}: no gRPC {probe} on port {port['containerPort']}")
            problem = token_problem(d["metadata"].get("namespace"), pod["spec"], c, secrets)
            if problem:
                sys.exit(f"{where}: the token: {problem}")
            print(f"ok: {where} (resources, probes, the token)")
    return workloads


def probes(probe, port):
    """Whether `probe` checks gRPC health on `port`: natively, or by `jsae health` (TLS)."""
    if probe.get("grpc", {}).get("port") == port:
        return True
    command = probe.get("exec", {}).get("command", [])
    addr = command[command.index("--addr") + 1] if "--addr" in command[:-1] else ""
    return command[:2] == ["jsae", "health"] and addr.endswith(f":{port}")


def token_problem(namespace, pod, container, secrets):
    """Why the container does not read the token, or None: JSAE_AUTH_TOKEN_FILE must name a
    key of a generated Secret, mounted, and readable by the pod's user."""
    want = next((e.get("value") for e in container.get("env") or [] if e["name"] == TOKEN_ENV),
                None)
    if not want:
        return f"no {TOKEN_ENV} in env"
    volumes = {v["name"]: v for v in pod.get("volumes") or []}
    for mount in container.get("volumeMounts") or []:
        secret = volumes.get(mount["name"], {}).get("secret")
        inside = want.startswith(mount["mountPath"].rstrip("/") + "/")
        if not secret or "subPath" in mount or not inside:
            continue
        name = secret.get("secretName")
        keys = secrets.get((namespace, name))
        if keys is None:
            return f"{want}: the secretGenerator makes no Secret {name} in namespace {namespace}"
        items = secret.get("items") or [{"key": k, "path": k} for k in keys]
        item = next((i for i in items if posixpath.join(mount["mountPath"], i["path"]) == want),
                    None)
        if item is None or item["key"] not in keys:
            return f"{want}: no key of the Secret {name} is mounted there"
        mode = item.get("mode", secret.get("defaultMode", 0o644))
        if not readable(mode, pod):
            return f"{want}: mode {mode:04o} and no fsGroup: the pod's user cannot read it"
        return None
    return f"{TOKEN_ENV}={want}: no Secret volume is mounted there"


def readable(mode, pod):
    """Whether the pod's (non-root) user reads a Secret file of `mode`: others may read it, or
    the pod has an fsGroup, which the kubelet makes the files' group, with read access."""
    return bool(mode & 0o004) or pod.get("securityContext", {}).get("fsGroup") is not None


def check_services(docs, workloads):
    for name, d in docs:
        if d["kind"] != "Service":
            continue
        sel = d["spec"]["selector"]
        if not any(all(labels.get(k) == v for k, v in sel.items())
                   for _, labels in workloads.values()):
            sys.exit(f"{name}: Service {d['metadata']['name']} selects no workload's pods")
        print(f"ok: {name}: Service {d['metadata']['name']} selects a workload")


def check_network_policies(docs, workloads):
    policies = [(name, d) for name, d in docs if d["kind"] == "NetworkPolicy"]
    deny = [d for _, d in policies if selects_all(d["spec"]["podSelector"])
            and "Ingress" in d["spec"].get("policyTypes", []) and not d["spec"].get("ingress")]
    if not deny:
        sys.exit("no default-deny ingress NetworkPolicy (podSelector {}, policyTypes [Ingress], "
                 "no ingress rules)")
    print("ok: a default-deny ingress NetworkPolicy")
    namespaces = {d["metadata"].get("namespace") for d, _ in workloads.values()}
    for name, d in policies:
        where = f"{name}: NetworkPolicy {d['metadata']['name']}"
        if d["metadata"].get("namespace") not in namespaces:
            sys.exit(f"{where}: not in the workloads' namespace {namespaces}")
        selectors = [d["spec"]["podSelector"]] + [
            peer["podSelector"] for rule in d["spec"].get("ingress", [])
            for peer in rule.get("from", [])
            if "podSelector" in peer and "namespaceSelector" not in peer]
        for sel in selectors:
            if not selected(sel, workloads):
                sys.exit(f"{where}: the selector {sel} selects no workload's pods")

    metrics = metrics_port(docs)
    for wname, (d, labels) in workloads.items():
        container_ports = {p["containerPort"]: p.get("name")
                           for c in d["spec"]["template"]["spec"]["containers"]
                           for p in c.get("ports", [])}
        ports = dict(container_ports)
        if metrics:
            ports.setdefault(metrics, None)
        for port, pname in ports.items():
            sources = admitted_sources(policies, labels, port, pname, workloads)
            if not sources:
                sys.exit(f"no NetworkPolicy admits anyone to {wname}:{port}: under the default "
                         "deny nothing reaches it")
            print(f"ok: {wname}:{port} reachable from {', '.join(sorted(sources))}")

    services = {d["metadata"]["name"]: d for _, d in docs if d["kind"] == "Service"}
    for wname, (d, labels) in workloads.items():
        for c in d["spec"]["template"]["spec"]["containers"]:
            for host, port in URL.findall(" ".join(c.get("args", []) + c.get("command", []))):
                target = services.get(host.split(".")[0])
                if target is None:
                    sys.exit(f"{wname}: dials {host}:{port}, which no Service names")
                for tname, tport, tpname in service_targets(target, int(port), workloads):
                    sources = admitted_sources(policies, workloads[tname][1], tport, tpname,
                                               workloads)
                    if not sources & {"anywhere", "this namespace", wname}:
                        sys.exit(f"{wname} dials {host}:{port}, but no NetworkPolicy admits it "
                                 f"to {tname}:{tport} (admitted: {sorted(sources)})")
                print(f"ok: {wname} may reach {host}:{port}")


def actor_deployment(docs):
    """(file, doc) of the one Deployment whose container runs `actor`."""
    found = [(name, d) for name, d in docs if d["kind"] == "Deployment"
             and any(((c.get("command") or []) + (c.get("args") or []))[:1] == ["actor"]
                     for c in d["spec"]["template"]["spec"]["containers"])]
    if len(found) != 1:
        names = [d["metadata"]["name"] for _, d in found]
        sys.exit(f"{len(found)} Deployments run `actor` {names}: want one (the stack's actor)")
    return found[0]


def check_actor_spread(name, d):
    """The actor pods spread over nodes: a podAntiAffinity term or a topologySpreadConstraint
    on the hostname whose selector matches the pods' own labels."""
    where = f"{name}: Deployment {d['metadata']['name']}"
    pod = d["spec"]["template"]
    labels, spec = pod["metadata"]["labels"], pod["spec"]
    ways = []
    for c in spec.get("topologySpreadConstraints") or []:
        if c["topologyKey"] == HOSTNAME and c.get("labelSelector") \
                and matches(c["labelSelector"], labels):
            ways.append(f"topologySpreadConstraints ({c['whenUnsatisfiable']})")
    anti = (spec.get("affinity") or {}).get("podAntiAffinity") or {}
    terms = [("required", t) for t in
             anti.get("requiredDuringSchedulingIgnoredDuringExecution") or []]
    terms += [("preferred", t["podAffinityTerm"]) for t in
              anti.get("preferredDuringSchedulingIgnoredDuringExecution") or []]
    for kind, t in terms:
        if t["topologyKey"] == HOSTNAME and same_namespace(t, d) and t.get("labelSelector") \
                and matches(t["labelSelector"], labels):
            ways.append(f"podAntiAffinity ({kind})")
    if not ways:
        sys.exit(f"{where}: the actor pods may all land on one node: no podAntiAffinity or "
                 f"topologySpreadConstraints on {HOSTNAME} selecting its pods {labels} (the "
                 "stack spreads its actors, max_replicas_per_node)")
    print(f"ok: {where} spreads its pods over nodes: {', '.join(ways)}")


def same_namespace(term, d):
    """Whether an affinity term looks at pods of the workload's own namespace."""
    if "namespaceSelector" in term:
        return True  # {} is every namespace; a narrower one is not worth resolving here
    spaces = term.get("namespaces")
    return not spaces or d["metadata"].get("namespace") in spaces


def check_actor_replicas(root, name, d):
    """The actor replicas equal the stack's default actor count (${JSAE_ACTORS:-N})."""
    stack = yaml.safe_load(read_sibling(root, "docker-stack.yml"))
    try:
        want = stack["services"]["actor"]["deploy"]["replicas"]
    except (KeyError, TypeError):
        sys.exit(f"{root}/../docker-stack.yml: no services.actor.deploy.replicas")
    if not isinstance(want, int):
        m = STACK_DEFAULT.match(str(want))
        if not m:
            sys.exit(f"docker-stack.yml: actor replicas {want!r} is neither a number nor "
                     "${NAME:-N}")
        want = int(m[1])
    have = d["spec"].get("replicas", 1)
    if have != want:
        sys.exit(f"{name}: Deployment {d['metadata']['name']} has {have} replicas, the swarm "
                 f"stack's actors default to {want} (docker-stack.yml); keep them in step")
    print(f"ok: {name}: Deployment {d['metadata']['name']} has {have} replicas, as the stack")


def check_settings(root, docs):
    """Every ConfigMap's config.toml holds the settings of deploy/config.toml."""
    want = tomllib.loads(read_sibling(root, "config.toml"))
    maps = [(name, d) for name, d in docs
            if d["kind"] == "ConfigMap" and "config.toml" in (d.get("data") or {})]
    if not maps:
        sys.exit("no ConfigMap holds config.toml (the workloads mount it at /etc/jsae)")
    for name, d in maps:
        where = f"{name}: ConfigMap {d['metadata']['name']} config.toml"
        try:
            have = tomllib.loads(d["data"]["config.toml"])
        except tomllib.TOMLDecodeError as e:
            sys.exit(f"{where}: not TOML: {e}")
        if have != want:
            sys.exit(f"{where} differs from deploy/config.toml: "
                     f"{'; '.join(differences(have, want))}")
        print(f"ok: {where}: the settings of deploy/config.toml ({', '.join(sorted(flat(want)))})")


def read_sibling(root, file):
    """The text of deploy/FILE, the folder above the manifests'."""
    path = os.path.join(root, os.pardir, file)
    try:
        with open(path) as f:
            return f.read()
    except FileNotFoundError:
        sys.exit(f"{os.path.normpath(path)} not found (the k8s folder's sibling, which the "
                 "manifests must match)")


def flat(table, prefix=""):
    """A TOML table as {dotted key: value}."""
    out = {}
    for k, v in table.items():
        if isinstance(v, dict):
            out.update(flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def differences(have, want):
    """What the ConfigMap's settings `have` differ in from deploy/config.toml's `want`."""
    have, want = flat(have), flat(want)
    out = []
    for k in sorted(have.keys() | want.keys()):
        if k not in want:
            out.append(f"{k} only in the ConfigMap")
        elif k not in have:
            out.append(f"{k} = {want[k]!r} missing from the ConfigMap")
        elif have[k] != want[k]:
            out.append(f"{k} = {have[k]!r} in the ConfigMap, {want[k]!r} in deploy/config.toml")
    return out or ["their (empty) tables differ"]


def metrics_port(docs):
    """The port of the ConfigMaps' JSAE_METRICS_LISTEN (host:port), or None when off."""
    for _, d in docs:
        listen = d.get("data", {}).get("JSAE_METRICS_LISTEN") if d["kind"] == "ConfigMap" else None
        if listen:
            return int(listen.rsplit(":", 1)[1])
    return None


def service_targets(service, port, workloads):
    """(workload, container port, port name) behind `port` of `service`."""
    entry = next((p for p in service["spec"]["ports"] if p["port"] == port), None)
    if entry is None:
        sys.exit(f"Service {service['metadata']['name']} has no port {port}")
    target = entry.get("targetPort", port)
    out = []
    for wname, (d, labels) in workloads.items():
        if not all(labels.get(k) == v for k, v in service["spec"]["selector"].items()):
            continue
        for c in d["spec"]["template"]["spec"]["containers"]:
            for p in c.get("ports", []):
                if target in (p["containerPort"], p.get("name")):
                    out.append((wname, p["containerPort"], p.get("name")))
    if not out:
        sys.exit(f"Service {service['metadata']['name']} port {port}: no container port {target}")
    return out


def admitted_sources(policies, labels, port, pname, workloads):
    """Who the policies let reach `port` of pods with `labels`: workload names, "anywhere",
    "this namespace", or a description of a namespace or address peer."""
    sources = set()
    for _, d in policies:
        spec = d["spec"]
        if not matches(spec["podSelector"], labels):
            continue
        for rule in spec.get("ingress", []):
            if not covers(rule.get("ports"), port, pname):
                continue
            peers = rule.get("from")
            if not peers:
                sources.add("anywhere")
            for peer in peers or []:
                if "ipBlock" in peer:
                    sources.add(f"addresses {peer['ipBlock']['cidr']}")
                elif "namespaceSelector" in peer:
                    sources.add(f"namespaces {peer['namespaceSelector']}")
                elif selects_all(peer["podSelector"]):
                    sources.add("this namespace")
                else:
                    sources.update(w for w, (_, l) in workloads.items()
                                   if matches(peer["podSelector"], l))
    return sources


def covers(ports, port, pname):
    """Whether a rule's `ports` (None: all) include the TCP `port` (named `pname`)."""
    if not ports:
        return True
    for p in ports:
        if p.get("protocol", "TCP") != "TCP":
            continue
        want = p.get("port")
        if want is None or want in (port, pname) or (
                isinstance(want, int) and want <= port <= p.get("endPort", want)):
            return True
    return False


def selects_all(selector):
    return not selector.get("matchLabels") and not selector.get("matchExpressions")


def selected(selector, workloads):
    return selects_all(selector) or any(matches(selector, l) for _, l in workloads.values())


def matches(selector, labels):
    """A label selector (matchLabels and matchExpressions) applied to `labels`."""
    if any(labels.get(k) != v for k, v in (selector.get("matchLabels") or {}).items()):
        return False
    for e in selector.get("matchExpressions") or []:
        key, op, values = e["key"], e["operator"], e.get("values", [])
        ok = {"In": key in labels and labels[key] in values,
              "NotIn": labels.get(key) not in values,
              "Exists": key in labels,
              "DoesNotExist": key not in labels}[op]
        if not ok:
            return False
    return True


if __name__ == "__main__":
    main()
