"""Task adapters to the gymnasium API and their registry: ``from envs import make, names``."""

from envs import acrobot as _acrobot  # noqa: F401  (registers acrobot_swingup)
from envs import carracing as _carracing  # noqa: F401  (registers carracing)
from envs import cartpole as _cartpole  # noqa: F401  (registers the cartpole tasks)
from envs import cartpole_variants as _cartpole_variants  # noqa: F401  (own-reward and changed-physics cart-poles)
from envs import lunarlander as _lunarlander  # noqa: F401  (registers lunarlander)
from envs import panda_reach as _panda_reach  # noqa: F401  (registers panda_reach)
from envs import pendulum as _pendulum  # noqa: F401  (registers pendulum_swingup)
from envs.registry import make, mj_model, names, register

__all__ = ["make", "mj_model", "names", "register"]
