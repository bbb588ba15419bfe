"""Prioritised scenes for DAgger collection: failure rates, each env's weights, their state."""

from __future__ import annotations

import numpy as np
import pytest

from vid2sim.training.scene_priority import MEMORY, ScenePriority


def test_the_scene_the_student_fails_on_gets_the_larger_share():
    p = ScenePriority(["a", "b", "c"], share=0.5)
    p.update([("a", False)] * 4 + [("b", True)] * 4)
    rates = p.failure_rates()
    assert rates[0] > rates[2] > rates[1] == pytest.approx(0.5 / 5)  # c: no episodes, the pooled rate 0.5
    w = p.weights(["a", "b"])
    assert w.sum() == pytest.approx(1.0) and w[0] > w[1] >= 0.5 / 2  # the uniform half is kept
    assert p.weights(["b"]) == pytest.approx([1.0])


def test_no_failures_or_no_share_draws_uniformly():
    p = ScenePriority(["a", "b"], share=0.8)
    np.testing.assert_allclose(p.weights(["a", "b"]), [0.5, 0.5])  # nothing seen yet
    p.update([("a", True), ("b", True)])
    np.testing.assert_allclose(p.weights(["a", "b"]), [0.5, 0.5])
    q = ScenePriority(["a", "b"], share=0.0)
    q.update([("a", False)])
    np.testing.assert_allclose(q.weights(["a", "b"]), [0.5, 0.5])
    with pytest.raises(ValueError, match="share"):
        ScenePriority(["a"], share=1.5)


def test_older_rounds_fade_and_the_state_round_trips():
    p = ScenePriority(["a", "b"], share=1.0)
    p.update([("a", False)])
    p.update([("b", False), ("x", False)])  # a scene the run does not train on is ignored
    np.testing.assert_allclose(p.episodes, [MEMORY, 1.0])
    np.testing.assert_allclose(p.failures, [MEMORY, 1.0])
    q = ScenePriority(["a", "b"], share=1.0)
    q.load_state_dict(p.state_dict())
    np.testing.assert_allclose(q.weights(["a", "b"]), p.weights(["a", "b"]))
    with pytest.raises(ValueError, match="other scenes"):
        ScenePriority(["a", "c"], share=1.0).load_state_dict(p.state_dict())
