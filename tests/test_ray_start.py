"""One way to start Ray (`factory.runtime.orchestrator.init_ray`), used by the factory and by
training: its checks and its retry of a start-up timeout, with `ray.init` stubbed (no Ray runtime
is started here)."""

from __future__ import annotations

import pytest

from vid2sim.factory.runtime import orchestrator
from vid2sim.factory.runtime.orchestrator import init_ray


class FakeRay:
    def __init__(self, failures: list[Exception]):
        self.failures, self.calls, self.shutdowns = list(failures), [], 0

    def is_initialized(self) -> bool:
        return False

    def init(self, **kwargs) -> None:
        self.calls.append(kwargs)
        if self.failures:
            raise self.failures.pop(0)

    def shutdown(self) -> None:
        self.shutdowns += 1


@pytest.fixture
def fake(monkeypatch):
    def make(*failures: Exception) -> FakeRay:
        ray = FakeRay(list(failures))
        monkeypatch.setattr(orchestrator, "ray", ray)
        return ray
    return make


def test_training_and_the_factory_start_ray_through_one_function():
    from vid2sim.training import rollouts

    assert rollouts.init_ray is init_ray and orchestrator.ensure_ray is init_ray


def test_a_local_start_that_times_out_is_retried(fake):
    ray = fake(Exception("The current node timed out during startup."))
    init_ray(num_cpus=2, runtime_env={"env_vars": {"A": "1"}})
    assert len(ray.calls) == 2 and ray.shutdowns == 1
    assert ray.calls[-1]["num_cpus"] == 2 and ray.calls[-1]["runtime_env"] == {"env_vars": {"A": "1"}}


def test_retries_stop_after_attempts_and_other_errors_raise_at_once(fake):
    timeout = "node timed out during startup"
    ray = fake(*(Exception(timeout) for _ in range(3)))
    with pytest.raises(Exception, match=timeout):
        init_ray(attempts=3)
    assert len(ray.calls) == 3
    ray = fake(RuntimeError("bad address"))
    with pytest.raises(RuntimeError, match="bad address"):
        init_ray("ray://nowhere:10001")
    assert len(ray.calls) == 1 and ray.calls[0]["address"] == "ray://nowhere:10001"


def test_a_local_runtime_needs_a_cpu(fake):
    ray = fake()
    with pytest.raises(ValueError, match="at least 1 CPU"):
        init_ray(num_cpus=0)
    assert ray.calls == []
