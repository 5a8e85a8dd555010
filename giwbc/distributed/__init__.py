"""Beyond one machine: environments on Ray actors, evaluation episodes as Ray tasks.

Ray is the optional ``ray`` extra (``pip install 'giwbc[ray]'``): nothing here imports it until a
function needs it, and then a missing Ray is one :class:`~giwbc.errors.UnavailableError` line.
:mod:`giwbc.distributed.vec_env` (the stable-baselines3 ``VecEnv``) also needs the ``train`` extra
and is imported by its users only.
"""

from giwbc.distributed.cluster import LOCAL, Connection, RayRunner, add_ray_argument, connect, require_ray

__all__ = ["LOCAL", "Connection", "RayRunner", "add_ray_argument", "connect", "require_ray"]
