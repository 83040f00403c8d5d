"""The runner tests' shared fixture: the simulated bench with a WireProxy in front of its exciter."""
from __future__ import annotations

import pytest

from simulators.bench import SimBench
from wire_proxy import WireProxy


@pytest.fixture
def bench():
    """(SimBench, WireProxy in front of its exciter)."""
    with SimBench() as sim:
        proxy = WireProxy(sim.endpoints.exciter_tcp)
        try:
            yield sim, proxy
        finally:
            proxy.close()
