"""docker/compose.yaml fits together (parsed; `make test-docker` runs it for real)."""

from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]


def test_agent_reaches_every_replica_and_keeps_its_run_on_a_volume():
    compose = yaml.safe_load((ROOT / "docker" / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"env-server", "agent"}
    server, agent = services["env-server"], services["agent"]
    for s in (server, agent):
        assert (ROOT / s["build"]["dockerfile"]).is_file()
    assert server["healthcheck"]["test"] == ["CMD", "million-env-health"]
    assert "50051" in server["expose"]
    assert agent["depends_on"]["env-server"]["condition"] == "service_healthy"
    args = agent["command"]
    assert args[args.index("--env-server") + 1] == "env-server:50051", (
        "the service name"
    )
    (volume,) = agent["volumes"]
    name, mount = volume.split(":")
    assert name in compose["volumes"]
    assert args[args.index("--run-dir") + 1].startswith(mount + "/")
