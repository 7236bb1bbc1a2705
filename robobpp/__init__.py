"""robobpp: closed-loop benchmark and evaluation service for robotic online 3D bin packing."""

__version__ = "0.1.0"

#: The Gymnasium id of the packing env (robobpp/env.py); registered when robobpp is imported.
GYM_ENV_ID = "robobpp/Pack-v0"
#: Episode step limit of the registered env: above any dataset group, so it never cuts a real episode.
GYM_MAX_EPISODE_STEPS = 1000


def register_gym_envs() -> None:
    """Register ``robobpp/Pack-v0`` with Gymnasium without importing the env module (idempotent).

    Gymnasium ≥ 1.0 has no plugin entry points, so registration rides on ``import robobpp``; the
    ``gymnasium.envs`` entry point in pyproject.toml points here for tools that still load plugins.
    """
    import gymnasium

    if GYM_ENV_ID not in gymnasium.registry:
        gymnasium.register(
            GYM_ENV_ID, entry_point="robobpp.env:PackEnv", max_episode_steps=GYM_MAX_EPISODE_STEPS
        )


register_gym_envs()
