"""The Kubernetes manifests (deploy/k8s) are well-formed and fit together.

No cluster is needed: the YAML is parsed and the pieces that must agree are checked
(kinds, selectors against pod labels, ports, the headless Service, the volume claim,
the agent's --env-server against the Service's DNS name and port).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

K8S = Path(__file__).resolve().parents[2] / "deploy" / "k8s"


def load(name: str) -> dict[str, dict]:
    docs = [d for d in yaml.safe_load_all((K8S / name).read_text()) if d is not None]
    for d in docs:
        assert {"apiVersion", "kind", "metadata"} <= d.keys(), d
        assert d["metadata"]["name"], d
    return {d["kind"]: d for d in docs}


@pytest.fixture(scope="module")
def env_server() -> dict[str, dict]:
    return load("env-server.yaml")


@pytest.fixture(scope="module")
def agent() -> dict[str, dict]:
    return load("agent.yaml")


def selects(selector: dict[str, str], labels: dict[str, str]) -> bool:
    return bool(selector) and all(labels.get(k) == v for k, v in selector.items())


def test_env_servers_are_a_deployment_behind_a_headless_service(env_server):
    assert set(env_server) == {"Deployment", "Service"}
    deployment, service = env_server["Deployment"], env_server["Service"]
    assert deployment["apiVersion"] == "apps/v1"
    assert service["apiVersion"] == "v1"
    spec = deployment["spec"]
    pod_labels = spec["template"]["metadata"]["labels"]
    assert selects(spec["selector"]["matchLabels"], pod_labels)
    assert spec["replicas"] >= 2
    assert service["spec"]["clusterIP"] == "None", "headless: DNS lists every pod"
    assert selects(service["spec"]["selector"], pod_labels)


def test_ports_and_probes_agree(env_server):
    pod = env_server["Deployment"]["spec"]["template"]["spec"]
    (container,) = pod["containers"]
    ports = {p["name"]: p["containerPort"] for p in container["ports"]}
    assert ports == {"grpc": 50051}, "the image's server listens on 0.0.0.0:50051"
    for probe in ("readinessProbe", "livenessProbe"):
        assert container[probe]["grpc"]["port"] == ports["grpc"], probe
    (port,) = env_server["Service"]["spec"]["ports"]
    assert port["port"] == ports["grpc"]
    assert port["targetPort"] in (ports["grpc"], "grpc")


def test_agent_is_a_job_with_its_run_directory_on_a_claim(agent, env_server):
    assert set(agent) == {"PersistentVolumeClaim", "Job"}
    job = agent["Job"]
    assert job["apiVersion"] == "batch/v1"
    pod = job["spec"]["template"]["spec"]
    assert pod["restartPolicy"] in ("OnFailure", "Never")
    (container,) = pod["containers"]
    volumes = {v["name"]: v for v in pod["volumes"]}
    (mount,) = container["volumeMounts"]
    claim = volumes[mount["name"]]["persistentVolumeClaim"]["claimName"]
    assert claim == agent["PersistentVolumeClaim"]["metadata"]["name"]
    assert agent["PersistentVolumeClaim"]["spec"]["resources"]["requests"]["storage"]

    args = container["args"]
    flag = {
        args[i]: args[i + 1] for i in range(len(args) - 1) if args[i].startswith("--")
    }
    assert flag["--run-dir"].startswith(mount["mountPath"] + "/")
    assert (K8S.parents[1] / flag["--config"]).is_file(), "a config the image carries"
    service = env_server["Service"]
    assert (
        flag["--env-server"]
        == f"{service['metadata']['name']}:{service['spec']['ports'][0]['port']}"
    )


def test_kustomization_lists_every_manifest():
    kustomization = yaml.safe_load((K8S / "kustomization.yaml").read_text())
    assert kustomization["kind"] == "Kustomization"
    manifests = sorted(
        p.name for p in K8S.glob("*.yaml") if p.name != "kustomization.yaml"
    )
    assert sorted(kustomization["resources"]) == manifests
