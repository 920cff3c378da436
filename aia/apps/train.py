"""``aia-train``: train a DQN, Double DQN or ADFQ policy on a tracking setting (Hydra app).

``aia-train --help`` lists the config groups (env, algo, exploration, logger) and every field.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from aia.train import train


@hydra.main(config_path="pkg://aia.conf", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """Entry point of ``aia-train``."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    choices = HydraConfig.get().runtime.choices
    print(f"training {cfg.algo.name} ({cfg.exploration.name}) on {choices.get('env')} for {cfg.frames} frames, "
          f"seed {cfg.seed}")
    state = train(cfg, out_dir)
    last = f"{state.eval_scores[-1]:.1f}" if state.eval_scores else "n/a"
    print(f"{state.frames} frames, {state.episodes} episodes, {state.updates} updates; last eval score {last}")
    print(f"log written to {out_dir} (checkpoint: {out_dir / 'checkpoints' / 'last.pt'})")


if __name__ == "__main__":
    main()
