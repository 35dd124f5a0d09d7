"""A real env server (the installed console script) for the client and server tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from million_env.server_process import start_server, stop_server


@pytest.fixture(scope="session")
def server_address() -> Iterator[str]:
    process, address = start_server("--max-envs-per-handle", "32", "--max-envs-total", "200")
    yield address
    stop_server(process)
