"""What rendering shows: titles inside the frame, and ``human`` mode drawing every step, or saying once that it
cannot."""

from __future__ import annotations

import pytest

import mrcomm_env
from mrcomm_baselines import default_policy, make_policy
from mrcomm_env.core import render
from mrcomm_env.registry import env_ids


@pytest.mark.parametrize("env_id", env_ids())
def test_the_title_of_every_frame_lies_inside_it(env_id):
    env = mrcomm_env.make(env_id, render_mode="rgb_array")
    observations, _ = env.reset(seed=0)
    policy = make_policy(env_id, default_policy(env_id))
    policy.reset(env.local_views(), 0)
    for _ in range(3):
        observations, *_ = env.step(policy.act(observations, env.local_views()))
    drawn = []
    frame = render.to_rgb_array(lambda ax: (env._render(ax), drawn.append(ax)))
    ax = drawn[0]
    box = ax.title.get_window_extent(ax.figure.canvas.get_renderer())
    height, width = frame.shape[:2]
    assert ax.title.get_text(), "every frame says what it shows"
    assert 0 <= box.x0 and box.x1 <= width and box.y1 <= height, (ax.title.get_text(), box, frame.shape)


def test_a_long_title_is_shrunk_then_wrapped_to_fit():
    text = "step 5: disagreement 0.000 (red: cells on which the maps differ), and a great deal more words"
    drawn = []
    render.to_rgb_array(lambda ax: (ax.set_title(text), drawn.append(ax)))
    ax = drawn[0]
    box = ax.title.get_window_extent(ax.figure.canvas.get_renderer())
    assert "\n" in ax.title.get_text() and ax.title.get_text().replace("\n", " ") == text
    assert 0 <= box.x0 and box.x1 <= 400


def test_human_mode_without_a_display_says_so_once_and_draws_nothing(monkeypatch):
    monkeypatch.setattr(render, "has_display", lambda: False)
    monkeypatch.setattr(render, "_warned_no_display", False)
    env = mrcomm_env.make(env_ids()[0], render_mode="human")
    with pytest.warns(RuntimeWarning, match="no display") as caught:
        env.reset(seed=0)
        for _ in range(3):
            env.step({agent: env.action_space(agent).sample() for agent in env.agents})
    assert len([w for w in caught if issubclass(w.category, RuntimeWarning)]) == 1
    assert env.render() is None


def test_human_mode_draws_at_reset_and_every_step(monkeypatch):
    monkeypatch.setattr(render, "has_display", lambda: True)
    shown = []
    monkeypatch.setattr(render, "show_human", lambda draw, figure, fps: shown.append(draw) or "window")
    env = mrcomm_env.make(env_ids()[0], render_mode="human")
    env.reset(seed=0)
    for _ in range(3):
        env.step({agent: env.action_space(agent).sample() for agent in env.agents})
    assert len(shown) == 4
