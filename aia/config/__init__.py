"""The apps' configuration: typed schemas of aia-train, aia-eval and aia-rollout (:mod:`.schemas`, registered
with Hydra's ConfigStore), single-value checks (:mod:`.checks`), the one validation layer that reads the schemas
(:mod:`.validation`), the errors invalid input and failed runs are reported with (:mod:`.errors`), and
composing a config from code (:mod:`.composing`).

Nothing is imported here: :mod:`aia.envs.config` imports :mod:`.checks` while :mod:`.validation` imports the
env, so each module is imported by its own name.
"""
