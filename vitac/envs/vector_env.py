"""N task environments over worker processes (several per worker), dict observations in shared memory.

Autoreset is same-step: when an episode ends, the returned observation already starts the next
episode and `info["final_obs"][i]` holds the last observation of the ended one (for bootstrapping
truncations), with `info["final_info"][i]` its success statistics.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import signal
import traceback
from multiprocessing import shared_memory

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode

from vitac.envs.gym_env import TaskEnv
from vitac.utils.checks import check_groups

log = logging.getLogger(__name__)
RESTARTED = "environment worker restarted"  # the outcome of the episodes a crashed worker's restart ended
RESTARTABLE = ("step", "reset")  # commands after which a dead worker is replaced; others need its state


class _EnvGroup:
    """k environments stepped in sequence, writing observations into given arrays."""

    def __init__(self, config: dict, seeds: list[int], obs_arrays: dict, offset: int):
        self.envs = [TaskEnv(config, seed=s) for s in seeds]
        self.obs, self.offset = obs_arrays, offset

    def _write(self, i: int, obs: dict):
        for k, v in obs.items():
            self.obs[k][self.offset + i] = v

    def reset(self, seed: int | None):
        infos = []
        for i, env in enumerate(self.envs):
            obs, info = env.reset(seed=None if seed is None else seed + self.offset + i)
            self._write(i, obs)
            infos.append(info)
        return infos

    def step(self, actions: np.ndarray):
        rewards, terminated, truncated, infos = [], [], [], []
        for i, env in enumerate(self.envs):
            obs, reward, term, trunc, info = env.step(actions[i])
            if term or trunc:
                info = dict(info, final_obs={k: np.array(v) for k, v in obs.items()})
                obs, _ = env.reset()
            self._write(i, obs)
            rewards.append(reward)
            terminated.append(term)
            truncated.append(trunc)
            infos.append(info)
        return rewards, terminated, truncated, infos

    def set_randomization_scale(self, scale: float):
        for env in self.envs:
            env.set_randomization_scale(scale)

    def get_state(self):
        return [env.get_state() for env in self.envs]

    def set_state(self, states):
        for i, (env, state) in enumerate(zip(self.envs, states, strict=True)):
            env.set_state(state)
            self._write(i, env.observation())

    def close(self):
        for env in self.envs:
            env.close()


def _worker(pipe, config, seeds, shm_specs, offset):
    # A SIGTERM to the whole job (SLURM, `kill -- -PGID`) is the main process's to handle: it finishes its
    # iteration and saves it, then closes the workers; one that died first would lose that iteration.
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole process group: the same holds
    shms = {k: shared_memory.SharedMemory(name=name) for k, (name, _, _) in shm_specs.items()}
    arrays = {k: np.ndarray(shape, dtype, buffer=shms[k].buf) for k, (_, shape, dtype) in shm_specs.items()}
    group = _EnvGroup(config, seeds, arrays, offset)
    try:
        while True:
            command, payload = pipe.recv()
            if command == "close":
                break
            try:
                pipe.send(("ok", getattr(group, command)(*payload)))
            except Exception:  # report to the main process instead of dying silently
                pipe.send(("error", traceback.format_exc()))
    except KeyboardInterrupt:
        pass
    finally:
        group.close()
        for shm in shms.values():
            shm.close()


class TaskVectorEnv(gym.vector.VectorEnv):
    """gymnasium VectorEnv of `num_envs` environments of one task in `num_workers` processes.

    Args:
        config: the task's keys (a plain dict with its `_target_`, sent to the workers).
        num_envs: number of environments.
        num_workers: groups of environments stepped in parallel, each in a worker process; 0 steps every
            environment in this process.
        seed: environment i is seeded with seed + i.
        step_in_main: this process steps the first group itself while the workers step the others (so
            num_workers - 1 worker processes), instead of idling in between policy steps. On 2 cores, 3 busy
            processes lose time to scheduling: 16 privileged envs collect ~1.4x faster (docs/benchmarks.md).
        max_restarts: worker processes that die (the OOM killer, a crash in native code) during a step or a
            reset are replaced, up to this many times in all: the new worker's environments start new episodes,
            and the episodes the crash cut off end as truncations with the outcome `RESTARTED`. Past the limit,
            or during another command, a dead worker stops the run with its process id and exit code.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, config: dict, num_envs: int, num_workers: int = 0, seed: int = 0, step_in_main: bool = False,
                 max_restarts: int = 5):
        check_groups(num_envs, num_workers)
        self.num_envs, self.num_workers = num_envs, num_workers
        self.max_restarts, self.restarts = max_restarts, 0
        # The configured randomization scale (1: the paper's), which a curriculum overrides while it runs.
        self.configured_scale = float((config.get("randomization") or {}).get("scale", 1.0))
        probe = TaskEnv(config, seed=seed)
        self.single_observation_space, self.single_action_space = probe.observation_space, probe.action_space
        probe.close()
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self._shms, self.buffers = {}, {}
        for k, space in self.single_observation_space.spaces.items():
            shape = (num_envs, *space.shape)
            nbytes = int(np.prod(shape)) * np.dtype(space.dtype).itemsize
            shm = shared_memory.SharedMemory(create=True, size=max(nbytes, 1))
            self._shms[k] = shm
            self.buffers[k] = np.ndarray(shape, space.dtype, buffer=shm.buf)
        seeds = [seed + i for i in range(num_envs)]
        self._pipes, self._procs, self._local = [], [], None
        per = num_envs // max(num_workers, 1)
        if num_workers == 0 or step_in_main:
            self._local = _EnvGroup(config, seeds[:per], self.buffers, 0)
        self._first_worker, self._per, self._config, self._seed = (1 if step_in_main else 0), per, config, seed
        self._specs = {k: (shm.name, self.buffers[k].shape, self.buffers[k].dtype) for k, shm in self._shms.items()}
        for w in range(self._first_worker, num_workers):
            self._pipes.append(None)
            self._procs.append(None)
            self._start_worker(len(self._pipes) - 1, seeds[w * per:(w + 1) * per])
        self._closed = False

    def _start_worker(self, w: int, seeds: list[int]) -> None:
        """Start worker process w (of this process's list), stepping group first_worker + w."""
        ctx = mp.get_context("forkserver")
        parent, child = ctx.Pipe()
        offset = (self._first_worker + w) * self._per
        proc = ctx.Process(target=_worker, args=(child, self._config, seeds, self._specs, offset), daemon=True)
        proc.start()
        self._pipes[w], self._procs[w] = parent, proc

    def _restart(self, w: int, command: str):
        """Replace dead worker w, reset its environments and return its reply to `command` (step or reset)."""
        proc = self._procs[w]
        proc.join(timeout=1)
        self.restarts += 1
        log.warning("environment worker process %d died (exit code %s) during %r: restarted (%d of %d restarts); its "
                    "%d environments start new episodes", proc.pid, proc.exitcode, command, self.restarts,
                    self.max_restarts, self._per)
        offset = (self._first_worker + w) * self._per
        # New seeds: the replacement must not replay the episodes the crash may have come from.
        base = self._seed + self.num_envs * self.restarts + offset
        self._start_worker(w, [base + i for i in range(self._per)])
        self._pipes[w].send(("reset", (None,)))
        status, infos = self._receive(w, "reset")
        if status == "error":
            raise RuntimeError(f"restarted environment worker {w} failed in 'reset':\n{infos}")
        if command == "reset":
            return infos
        final = [dict(info, success=False, steps_to_success=-1, outcome=RESTARTED,
                      final_obs={k: self.buffers[k][offset + i].copy() for k in self.buffers})
                 for i, info in enumerate(infos)]
        return [0.0] * self._per, [False] * self._per, [True] * self._per, final

    def _call(self, command: str, payloads: list) -> list:
        """One payload per group: the workers start first, then this process runs its own group, if any."""
        remote = payloads[1:] if self._local is not None else payloads
        dead = set()
        for w, payload in enumerate(remote):
            try:
                self._pipes[w].send((command, payload))
            except (BrokenPipeError, ConnectionResetError):
                dead.add(w)
        try:
            local = [getattr(self._local, command)(*payloads[0])] if self._local is not None else []
        finally:  # the workers' replies are collected even when this process's group failed
            replies = []
            for w in range(len(self._pipes)):
                try:
                    replies.append(None if w in dead else self._receive(w, command))
                except RuntimeError:  # it died while working on the command
                    dead.add(w)
                    replies.append(None)
        if dead and (command not in RESTARTABLE or self.restarts + len(dead) > self.max_restarts):
            raise self._worker_died(min(dead), command)
        for w in sorted(dead):
            replies[w] = ("ok", self._restart(w, command))
        first = len(local)
        errors = [(first + w, body) for w, (status, body) in enumerate(replies) if status == "error"]
        if errors:
            group, trace = errors[0]
            raise RuntimeError(f"environment group {group} (a worker process) failed in {command!r}:\n{trace}")
        return local + [body for _, body in replies]

    def _receive(self, w: int, command: str):
        try:
            return self._pipes[w].recv()
        except (EOFError, ConnectionResetError) as err:
            raise self._worker_died(w, command) from err

    def _worker_died(self, w: int, command: str) -> RuntimeError:
        proc = self._procs[w]
        proc.join(timeout=1)
        restarts = f" after {self.restarts} restarts (max_restarts={self.max_restarts})" if command in RESTARTABLE else ""
        return RuntimeError(f"environment worker process {proc.pid} died (exit code {proc.exitcode}) during "
                            f"{command!r}{restarts}; a run continues from its last checkpoint with resume=<run dir>")

    def _split(self, x) -> list:
        groups = max(self.num_workers, 1)
        return np.array_split(np.asarray(x), groups) if x is not None else [None] * groups

    def _observation(self) -> dict:
        return {k: v.copy() for k, v in self.buffers.items()}

    def reset(self, *, seed: int | None = None, options=None):
        results = self._call("reset", [(seed,)] * max(self.num_workers, 1))
        infos = [info for group in results for info in group]
        return self._observation(), {"env_infos": infos}

    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float64)
        results = self._call("step", [(a,) for a in self._split(actions)])
        rewards, terminated, truncated, infos = [], [], [], []
        for r, te, tr, inf in results:
            rewards += r
            terminated += te
            truncated += tr
            infos += inf
        final_obs = {i: info.pop("final_obs") for i, info in enumerate(infos) if "final_obs" in info}
        return (self._observation(), np.array(rewards, np.float32), np.array(terminated), np.array(truncated),
                {"final_obs": final_obs, "env_infos": infos})

    def set_randomization_scale(self, scale: float) -> None:
        """Curriculum hook: every environment's randomization ranges, scaled about their midpoints."""
        self._call("set_randomization_scale", [(scale,)] * max(self.num_workers, 1))

    def get_state(self) -> list:
        return [s for group in self._call("get_state", [()] * max(self.num_workers, 1)) for s in group]

    def set_state(self, states: list) -> dict:
        per = self.num_envs // max(self.num_workers, 1)
        self._call("set_state", [(states[i * per:(i + 1) * per],) for i in range(max(self.num_workers, 1))])
        return self._observation()

    def close(self, **kwargs):
        if self._closed:
            return
        self._closed = True
        if self._local is not None:
            self._local.close()
        for pipe in self._pipes:
            try:
                pipe.send(("close", ()))
            except (BrokenPipeError, EOFError, ConnectionResetError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
        for shm in self._shms.values():
            shm.close()
            shm.unlink()
