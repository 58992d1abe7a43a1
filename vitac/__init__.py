"""vitac: visuo-tactile insertion policies on MuJoCo + dm_control composer."""

from vitac.api import load_policy, make_env, register_gym_ids

__version__ = "0.1.0"
__all__ = ["load_policy", "make_env"]

register_gym_ids()  # gymnasium.make("vitac/PegInsertion-v0"), ... (vitac.api.GYM_IDS)
