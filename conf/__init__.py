"""Hydra configs of aia, installed as the package ``aia.conf``.

Loading this package registers the typed schemas that the configs extend (the env presets' ``env_schema``; the
apps' and the train config groups' schemas, :mod:`aia.config.schemas`), so ``pkg://aia.conf`` composes wherever
it is used.
"""

import aia.config.schemas  # noqa: F401
import aia.envs.config  # noqa: F401
