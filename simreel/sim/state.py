"""A live env's state: read it (fast where that is exact), restore all of it, and check its layout.

- `read_state` / `FastStateReader`: the flat state dict of a live env.
- `restore_state`: put a recorded state back, all of it (task, custom keys, controller, step count).
- `check_rebuilt_layout` / `check_same_layout`: the one check that a live env's state layout is the one a
  recording needs, raising `simreel.errors.StateLayoutError` naming every leaf that differs.

Fast reads: ManiSkill 3.0.1's `get_state_dict()` builds a `Pose` and several torch tensors per object (~240 µs for
PickCube, a fifth of a CPU step). On the CPU sim with one env the same numbers come from one `pack()` of the
PhysX system; `FastStateReader` gathers them into numpy (~15 µs). It is used only where it gives the
very same values: a task that does not override `get_state_dict` (or only adds declared custom state
through `simreel.authoring.custom_state.CustomStateMixin`), registry objects of ManiSkill's own `Actor` /
`Articulation` classes, CPU sim, `num_envs == 1`. Its users (the recorder, the replay engine) check it
bit for bit against `get_state_dict()` with `matches()` and fall back to `get_state_dict()` on any
difference.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from simreel.errors import StateLayoutError, TaskCodeError
from simreel.model.state_tree import LeafSpec, flatten, layout_differences, layout_of, to_numpy, unflatten
from simreel.sim.step_rows import PackedRows

__all__ = [
    "FastStateReader",
    "read_state",
    "restore_state",
    "state_row",
    "live_layout",
    "check_rebuilt_layout",
    "check_same_layout",
]


def _base_get_state_dict() -> tuple[Any, ...]:
    from mani_skill.envs.sapien_env import BaseEnv

    from simreel.authoring.custom_state import CustomStateMixin

    return BaseEnv.get_state_dict, CustomStateMixin.get_state_dict


class FastStateReader:
    """`read()` → flat state dict (key path → (1, ...) float32 array) of a supported CPU env.

    Actors and articulations come from one call, the PhysX CPU system's `pack()`: a byte string of every rigid
    dynamic body's pose (q wxyz, p), linear and angular velocity, then of every articulation its root pose and
    velocities, qpos, qvel and joint drive targets, in the order of `px.rigid_dynamic_components` /
    `px.articulation_link_components` (SAPIEN 3.0.3's `PhysxSystemCpu::packState`). Where each state leaf's
    numbers sit in it is worked out once per scene; a read is then one gather, not a dozen pybind calls and
    concatenations per body. A scene whose bodies changed since (the byte string has another length) is read
    through `get_state_dict()`.
    """

    def __init__(self, unwrapped: Any) -> None:
        from mani_skill.utils.structs import Actor, Articulation

        u = unwrapped
        self.u = u
        self._px = u.scene.px
        bodies, articulations, self._nbytes = _packed_starts(self._px)
        zero = self._nbytes // 4  # `read` appends one 0.0 there: the velocities of kinematic actors
        index: list[int] = []
        slices: list[tuple[str, int, int]] = []
        reg = u.scene.state_dict_registry
        for name, actor in reg.actors.items():
            if type(actor) is not Actor or len(actor._objs) != 1:
                raise TypeError(name)
            kind = actor.px_body_type
            if kind == "static":
                continue
            s = bodies[actor._bodies[0]]
            velocities = list(range(s + 7, s + 13)) if kind == "dynamic" else [zero] * 6
            _add(slices, f"actors/{name}", index, [*range(s + 4, s + 7), *range(s, s + 4), *velocities])
        for name, art in reg.articulations.items():
            if type(art) is not Articulation or len(art._objs) != 1 or art.max_dof != art._objs[0].dof:
                raise TypeError(name)
            s, dof = articulations[art._objs[0]], art._objs[0].dof
            # root p, q, linear and angular velocity, then qpos and qvel
            _add(slices, f"articulations/{name}", index, [*range(s + 4, s + 7), *range(s, s + 4),
                                                         *range(s + 7, s + 13 + 2 * dof)])
        self.packed_rows = PackedRows(np.asarray(index, np.intp), tuple(slices))
        """What turns a block of `capture`s into the actor and articulation leaves, key path → (k, 1, ...) float32."""
        self.packed_keys = frozenset(key for key, _, _ in slices)
        """The state leaves a `capture` holds (the others are `extras`)."""
        self._custom = type(u).get_state_dict is _base_get_state_dict()[1]
        self._agent = getattr(u, "agent", None)
        if self._agent is not None and not self._controller_state():
            self._agent = None  # a controller without targets (pd_joint_pos, ...) never has state: skip asking

    @classmethod
    def for_env(cls, unwrapped: Any) -> FastStateReader | None:
        """A reader for `unwrapped`, or None where only `get_state_dict()` gives the right answer."""
        from mani_skill.envs.scene import ManiSkillScene

        u = unwrapped
        if getattr(u, "gpu_sim_enabled", True) or int(u.num_envs) != 1:
            return None
        if type(u).get_state_dict not in _base_get_state_dict():
            return None
        if type(u.scene).get_sim_state is not ManiSkillScene.get_sim_state:
            return None
        try:
            return cls(u)
        except (TypeError, AttributeError, IndexError, KeyError):
            return None

    @property
    def px(self) -> Any:
        """The PhysX system this reader reads."""
        return self._px

    def read(self) -> dict[str, np.ndarray]:
        packed = self.capture()
        if packed is None:  # bodies were added or removed since the reader was built
            return read_state(self.u)
        out = {key: rows[0] for key, rows in self.packed_rows([packed]).items()}
        out.update(self.extras())
        return out

    def capture(self) -> bytes | None:
        """The actors' and articulations' state now, packed (`packed_rows` makes leaves of it, later), or None where
        the scene's bodies changed since the reader was built."""
        packed = self._px.pack()
        return packed if len(packed) == self._nbytes else None

    def extras(self) -> dict[str, np.ndarray]:
        """The leaves `pack()` does not hold, read now: the controller's targets and the task's custom state."""
        out: dict[str, np.ndarray] = {}
        if self._agent is not None:
            controller = self._controller_state()
            if controller:
                out.update(flatten({"controller": controller}))
        if self._custom:
            from simreel.authoring.custom_state import get_custom_state

            out.update({k: to_numpy(v) for k, v in get_custom_state(self.u).items()})
        return out

    def _controller_state(self) -> dict[str, Any]:
        """The controller's entry of the state dict now, as `get_state_dict()` makes it (empty: none)."""
        agent = self._agent
        controller = agent.get_controller_state()
        if isinstance(agent.controller, dict):
            controller = {k: v for k, v in controller.items() if len(v) > 0}
        return controller if len(controller) > 0 else {}

    def matches(self) -> bool:
        """Whether `read()` equals `get_state_dict()` now, bit for bit, key for key."""
        return self.equals(flatten(self.u.get_state_dict()))

    def equals(self, state: Mapping[str, np.ndarray]) -> bool:
        """Whether `read()` equals `state` (a flat state dict read through `get_state_dict()` now), bit for bit, key
        for key."""
        return self.capture_equal_to(state) is not None

    def capture_equal_to(self, state: Mapping[str, np.ndarray]) -> bytes | None:
        """A `capture()` now, where it and `extras()` read as `state` (a flat state dict read through
        `get_state_dict()` now), bit for bit, key for key; else None (also where the scene's bodies changed since
        the reader was built). The packed leaves are compared as one byte string: one comparison, not one per leaf."""
        packed = self.capture()
        if packed is None:
            return None
        extras = self.extras()
        slices = self.packed_rows.slices
        if list(state) != [key for key, _, _ in slices] + list(extras):
            return None
        leaves = [state[key] for key, _, _ in slices]
        if any(a.dtype != np.float32 or a.shape != (1, b - s) for a, (_, s, b) in zip(leaves, slices, strict=True)):
            return None
        if self.packed_rows.gather([packed]).tobytes() != np.concatenate([a.reshape(-1) for a in leaves]).tobytes():
            return None
        same = all(_same_bits(a, state[key]) for key, a in extras.items())
        return packed if same else None


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


_BODY_FLOATS = 13
"""A body in `pack()`: pose (q wxyz, p xyz), linear velocity, angular velocity."""


def _add(slices: list[tuple[str, int, int]], key: str, index: list[int], leaf: list[int]) -> None:
    """Note state leaf `key` as the float32s `leaf` of a packed state, gathered after those in `index` so far."""
    slices.append((key, len(index), len(index) + len(leaf)))
    index.extend(leaf)


def _packed_starts(px: Any) -> tuple[dict[Any, int], dict[Any, int], int]:
    """Where each rigid dynamic body and each articulation starts in `px.pack()` (in float32s), and its length in
    bytes; `TypeError` where that length is not the one `pack()` returns (another SAPIEN than 3.0.3's layout)."""
    bodies, articulations, at = {}, {}, 0
    for body in px.rigid_dynamic_components:
        bodies[body] = at
        at += _BODY_FLOATS
    for link in px.articulation_link_components:
        if link.is_root:
            art = link.articulation
            articulations[art] = at
            at += _BODY_FLOATS + 2 * art.dof + 2 * sum(j.dof for j in art.active_joints)  # + qpos, qvel, drive targets
    if 4 * at != len(px.pack()):
        raise TypeError("unknown pack() layout")
    return bodies, articulations, 4 * at


def read_state(unwrapped: Any) -> dict[str, np.ndarray]:
    """The flat state dict of a live env, key path → (num_envs, ...) array (ManiSkill's `get_state_dict()`)."""
    return flatten(unwrapped.get_state_dict())


# ------------------------------------------------------------------------------------------ restoring
# ManiSkill 3.0.1's `BaseEnv.set_state_dict` restores actors and articulations (and, through a task's override
# such as `CustomStateMixin`, custom task keys) but ignores the ``controller`` entry that `get_state_dict`
# returns for target-based control modes (``pd_ee_target_delta_pos``, ...): the controller keeps the target of
# the env's own last step. `restore_state` also hands the controller its saved targets, and sets the episode's
# elapsed step count, which the time limit and ``info["elapsed_steps"]`` read.


def state_row(env_states: Mapping[str, np.ndarray], t: int) -> dict[str, np.ndarray]:
    """Row t of flat (T+1, ...) state arrays, each with a batch dimension of 1."""
    return {p: a[t : t + 1] for p, a in env_states.items()}


def _to_torch(tree: Any, device: Any) -> Any:
    import torch

    if isinstance(tree, Mapping):
        return {k: _to_torch(v, device) for k, v in tree.items()}
    return torch.as_tensor(np.array(tree), device=device)  # a copy: controllers may modify targets in place


def restore_state(unwrapped: Any, flat_state: Mapping[str, np.ndarray], *, elapsed_steps: int | None = None) -> None:
    """Put the env into the recorded state `flat_state` (key path → (1, ...) array).

    Calls the task's `set_state_dict` (actors, articulations, custom keys), then the agent's
    `set_controller_state` with the saved ``controller`` entry, and sets the elapsed step count when given.
    """
    u = unwrapped
    state = _to_torch(unflatten(flat_state), u.device)
    try:
        u.set_state_dict(state)
    except Exception as e:
        if not _users_code(type(u).set_state_dict):
            raise
        raise TaskCodeError(f"{type(u).__name__}.set_state_dict raised {type(e).__name__}: {e} while a state was "
                            "restored into it; fix the task's set_state_dict") from e
    controller = state.get("controller")
    agent = getattr(u, "agent", None)
    if controller and agent is not None:
        agents = getattr(agent, "agents_dict", None)  # MultiAgent: one controller state per robot uid
        if agents is not None:
            for uid, sub in controller.items():
                if uid in agents and sub:
                    agents[uid].set_controller_state(sub)
        else:
            agent.set_controller_state(controller)
    if elapsed_steps is not None:
        u._elapsed_steps[...] = int(elapsed_steps)


def _users_code(function: Any) -> bool:
    """Whether `function` is a user's (a task's override), not ManiSkill's or simreel's own."""
    module = getattr(function, "__module__", "") or ""
    return module.split(".")[0] not in ("mani_skill", "simreel")


# ------------------------------------------------------------------------------------------ the layout
def live_layout(unwrapped: Any) -> dict[str, LeafSpec]:
    """The per-env layout (key path → shape, dtype) of a live env's state dict."""
    return layout_of(read_state(unwrapped), batched=True)


def _layout_error(want: Mapping[str, LeafSpec], have: Mapping[str, LeafSpec], labels: tuple[str, str],
                  what: str, fix: str) -> StateLayoutError | None:
    diffs = layout_differences(want, have, old_label=labels[0], new_label=labels[1])
    if not diffs:
        return None
    more = f"; {len(diffs) - 4} more" if len(diffs) > 4 else ""
    return StateLayoutError(f"{what} ({'; '.join(diffs[:4])}{more}); {fix}")


def check_rebuilt_layout(unwrapped: Any, env_id: str, recorded: Mapping[str, LeafSpec], *,
                         new_controller_state: bool = False) -> None:
    """Raise `StateLayoutError` unless the env rebuilt for a recording of `env_id` has its `recorded` layout;
    `new_controller_state`: but for the ``controller/`` entries the recording lacks (an env rebuilt in another control
    mode, whose controller keeps a target)."""
    live = live_layout(unwrapped)
    if new_controller_state:
        live = {k: v for k, v in live.items() if k in recorded or not k.startswith("controller/")}
    error = _layout_error(
        recorded, live, ("recorded", "rebuilt"),
        f"the rebuilt {env_id} has another state layout than the recording",
        "rebuild it with the task version and --import modules that recorded it (see `simreel inspect`)",
    )
    if error is not None:
        raise error


def check_same_layout(env_id: str, first: Mapping[str, LeafSpec], now: Mapping[str, LeafSpec]) -> None:
    """Raise `StateLayoutError` when a task's state layout `now` is not the `first` one, the recording's (read from
    the env as the recorder was made, before any episode)."""
    error = _layout_error(
        first, now, ("when the recording started", "now"),
        f"the state dict of {env_id} changed after a reset",
        "one recording needs one layout — register merged views for per-episode objects, with a `state_dof` bound "
        "where their joints vary (see simreel.authoring.heterogeneous)",
    )
    if error is not None:
        raise error
