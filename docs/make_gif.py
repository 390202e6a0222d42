"""Draw the README's picture: an animated episode of the decentralised view (``render_mode="rgb_array"``).

    python docs/make_gif.py                      # writes docs/assets/episode.gif
    python docs/make_gif.py --config n5_m2_dt120 --steps 40 --out /tmp/episode.gif

The rule-based container agents (each requests a PU when its container is within one volume unit
of its optimum, or past it) act on ``--config`` under the paper's test protocol (δ = 120 s),
seeded; every frame is the environment's own ``render()``, scaled down and written with Pillow.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from containergym_marl import container_agents_v0
from containergym_marl.core.params import PlantParams
from containergym_marl.policies.rule_based import RuleBasedAgents


def episode_frames(config: str, steps: int, seed: int = 0) -> list[np.ndarray]:
    """``steps + 1`` frames (the reset and every step) of the rule-based agents on ``config``."""
    env = container_agents_v0.parallel_env(config, protocol="paper_test", render_mode="rgb_array")
    policy = RuleBasedAgents(PlantParams.from_config(env.config))
    observations, _ = env.reset(seed=seed)
    frames = [env.render()]
    for _ in range(steps):
        if not env.agents:
            break
        observations, *_ = env.step(policy.act(observations, env))
        frames.append(env.render())
    env.close()
    return frames


def write_gif(frames: list[np.ndarray], path: str | Path, scale: float = 0.6, frame_ms: int = 250) -> Path:
    """An animated GIF of ``frames`` (uint8 ``(H, W, 3)``), each scaled by ``scale``, on one palette."""
    images = [Image.fromarray(f) for f in frames]
    size = (round(images[0].width * scale), round(images[0].height * scale))
    images = [im.resize(size, Image.LANCZOS) for im in images]
    palette = images[len(images) // 2].quantize(colors=64, method=Image.Quantize.MEDIANCUT)
    images = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=frame_ms, loop=0, optimize=True)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--config", default="n11_m2_dt120")
    parser.add_argument("--steps", type=int, default=60, help="steps after the reset (one frame each)")
    parser.add_argument("--seed", type=int, default=10_000, help="the episode's seed (10000: the first test episode)")
    parser.add_argument("--scale", type=float, default=0.6)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "assets" / "episode.gif")
    ns = parser.parse_args(argv)
    path = write_gif(episode_frames(ns.config, ns.steps, ns.seed), ns.out, ns.scale)
    print(f"wrote {path} ({path.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
