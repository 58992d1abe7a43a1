"""Tasks on the shared robot and sensors; each is a folder with its config, props, task and oracle."""

from importlib import import_module

import vitac.sim  # noqa: F401  (selects headless EGL before dm_control loads)
from vitac.utils.checks import refuse

# Runs written before tasks had a group (the `env` key) were insertion runs.
DEFAULT_TASK_CONFIG = "vitac.tasks.insertion.config.InsertionConfig"


def import_object(path: str):
    """The object at a dotted path `package.module.Name`."""
    module, _, name = path.rpartition(".")
    return getattr(import_module(module), name)


def make_task_config(settings: dict | None):
    """A task's validated config from plain keys; `_target_` names its config class (conf/task/<name>.yaml)."""
    from vitac.tasks.config import GraspTaskConfig

    settings = dict(settings or {})
    target = settings.pop("_target_", None) or DEFAULT_TASK_CONFIG
    try:
        cls = import_object(target)
    except (ImportError, AttributeError, ValueError):
        cls = None
    if not (isinstance(cls, type) and issubclass(cls, GraspTaskConfig)):
        refuse("task._target_", target, "the dotted path of a GraspTaskConfig subclass, e.g. " + DEFAULT_TASK_CONFIG)
    return cls.from_dict(settings)
