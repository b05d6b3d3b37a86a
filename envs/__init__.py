"""Task adapters to the gymnasium API and their registry: ``from envs import make, names``."""

from envs import carracing as _carracing  # noqa: F401  (registers carracing)
from envs import cartpole as _cartpole  # noqa: F401  (registers the cartpole tasks)
from envs import cartpole_variants as _cartpole_variants  # noqa: F401  (own-reward and changed-physics cart-poles)
from envs import lunarlander as _lunarlander  # noqa: F401  (registers lunarlander)
from envs import panda_reach as _panda_reach  # noqa: F401  (registers panda_reach)
from envs.registry import make, mj_model, names, register

__all__ = ["make", "mj_model", "names", "register"]
