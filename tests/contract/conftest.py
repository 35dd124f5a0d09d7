"""Contract-test options and the server under test.

``pytest tests/contract --env-server HOST:PORT`` tests a running server; without
the flag the bundled ``million-env-server`` is started on a free loopback port for
the session. ``--env ID[:key=value,...]`` (repeatable) chooses the env ids.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from contract_support import Api, EnvCase
from million_env.server_process import running_server, wait_until_serving

# Extend this list as the server gains env families; every entry runs every
# generic check. Meta-World and MILLION ids carry the kwargs they need.
DEFAULT_ENVS = (
    "Pendulum-v1",
    "CartPole-v1",
    "metaworld/ML1-train:task=reach-v3",
    # Meta-World's own id; its goal set is random unless the seed kwarg fixes it.
    "Meta-World/MT1:env_name=reach-v3,seed=1",
    "million/PointGoal",
    "million/ML10-train",
)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("contract", "MILLION env API contract tests")
    group.addoption(
        "--env-server",
        default=None,
        metavar="HOST:PORT",
        help="test this running server instead of starting the bundled one",
    )
    group.addoption(
        "--env",
        action="append",
        default=None,
        metavar="ID[:key=value,...]",
        help=f"env id (with kwargs) to test; repeatable (default: {', '.join(DEFAULT_ENVS)})",
    )


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "contract_check(id): the checks.toml check a test implements"
    )


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "env_case" in metafunc.fixturenames:
        texts = metafunc.config.getoption("--env") or list(DEFAULT_ENVS)
        cases = [EnvCase.parse(t) for t in texts]
        metafunc.parametrize(
            "env_case", cases, ids=[str(c) for c in cases], scope="module"
        )


@pytest.fixture(scope="session")
def server_address(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    given = request.config.getoption("--env-server")
    if given:
        wait_until_serving(given, 30.0)
        yield given
        return
    log_path = tmp_path_factory.mktemp("env-server") / "server.log"
    with (
        log_path.open("w") as log,
        running_server(
            "--max-envs-per-handle", "64", "--max-envs-total", "512", log=log
        ) as address,
    ):
        yield address


@pytest.fixture(scope="session")
def api(server_address: str) -> Iterator[Api]:
    client = Api(server_address)
    yield client
    client.channel.close()
