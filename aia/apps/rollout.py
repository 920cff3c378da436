"""``aia-rollout``: score scripted policies (random, belief pursuit) on a batch of tracking worlds.

Runs one episode in each of ``num_worlds`` worlds per policy, prints the score (SPEC 9), the shaped
return and the belief error (mean distance from the belief means to the true targets), and writes
``rollout.json`` in the Hydra run directory (:func:`~aia.evaluation.standalone.score_scripted`). ``aia-rollout
--help`` lists the config. The env and the policies (torch) load once the config is valid.
"""

from __future__ import annotations

from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from aia.apps.hydra_app import hydra_app
from aia.apps.output_files import write_json
from aia.config.validation import validate_rollout_config
from aia.evaluation.standalone import score_scripted


@hydra_app("aia-rollout", config_name="rollout")  # invalid input: one line on stderr, exit 2
def main(cfg: DictConfig) -> None:
    """Entry point of ``aia-rollout`` (invalid input: one line on stderr, exit status 2)."""
    validate_rollout_config(cfg)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    choice = HydraConfig.get().runtime.choices.get("env")
    print(f"setting {choice}: map {cfg.env.map}, {cfg.env.num_targets} target(s), {cfg.env.max_steps} steps, "
          f"{cfg.num_worlds} worlds, seed {cfg.seed}")
    results = [score_scripted(cfg, name) for name in cfg.policies]
    print(f"{'policy':<10}{'score mean':>12}{'std':>9}{'return':>10}{'error m':>9}{'observed':>10}{'frames/s':>11}")
    for r in results:
        print(f"{r['policy']:<10}{r['score_mean']:>12.1f}{r['score_std']:>9.1f}{r['return_mean']:>10.1f}"
              f"{r['belief_error']:>9.2f}{r['observed_fraction']:>10.2f}{r['frames_per_s']:>11,.0f}")
    log = out_dir / "rollout.json"
    write_json(log, {"config": OmegaConf.to_container(cfg, resolve=True), "setting": choice, "results": results})
    print(f"log written to {log}")


if __name__ == "__main__":
    main()
