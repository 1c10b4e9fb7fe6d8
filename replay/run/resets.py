"""How a replay starts an episode: its reset reproduced (`simreel.sim.rebuild.reset_to_episode`) and this replayer
bound to the scene (fast state reader, body poses, contacts), the scene compared with its recorded fingerprint, the
step before the reset re-run (`SceneBefore`), and an unseeded (or stale-seeded) episode started where it began.

`EpisodeResets` is a part of `simreel.replay.run.engine.EpisodeReplayer` (a base class of it): it works on the
replayer's env and its scene's bookkeeping."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeRows
from simreel.model.blocks import StepBlock
from simreel.model.meta import EpisodeMeta
from simreel.replay.run.blocks import RecordedStates
from simreel.replay.run.guards import task_code_errors
from simreel.sim.fingerprint import SceneDifference
from simreel.sim.rebuild import UNSEEDED_WITHOUT_STATES, EpisodeReset, reset_to_episode
from simreel.sim.state import FastStateReader, check_rebuilt_layout, restore_state

__all__ = ["EpisodeResets", "SceneBefore"]


@dataclass(frozen=True)
class SceneBefore:
    """The step the recorder's scene simulated last before an episode's reset, whose contacts the observations at
    that reset read: episode `episode`'s step from its state row `step` (`state`, each leaf (1, ...)) with `action`;
    ``SceneBefore()``: none, the scene was just built (no contacts). A restoring replay re-runs it before the reset
    (`EpisodeReplayer.rerun_step_before`)."""

    episode: EpisodeMeta | None = None
    state: dict[str, np.ndarray] = field(default_factory=dict)
    action: np.ndarray | None = None
    step: int = 0


class EpisodeResets:
    """The start of each episode's replay (`EpisodeReplayer`'s; see the module)."""

    def reset_for(self, ep: EpisodeMeta) -> EpisodeReset:
        """Reset the env the way episode `ep` was reset (scene, seed, options: `simreel.sim.rebuild.reset_to_episode`);
        returns what was done, with this replayer's own limits added (body poses, contacts; also those its scene
        met at the reset of `rerun_step_before`, which rebuilt it)."""
        done, _ = self._reset_scene(ep)
        done.limits[:0], self._carried = self._carried, []
        return done

    def _reset_scene(self, ep: EpisodeMeta) -> tuple[EpisodeReset, list[str]]:
        """`reset_for`'s reset, and the limits this replayer met binding to a rebuilt scene (in its limits too)."""
        u = self.u
        bound: list[str] = []
        done = reset_to_episode(self.env, ep, scene_seed=self._scene_seed)
        self._scene_seed = done.scene_seed
        self._scene_builds += done.scene_builds
        self._stepped = self._stepped and not done.scene_builds
        if self._fast_allowed:
            if self._fast is None or self._fast_scene != self._scene_builds:  # a rebuilt scene has new bodies
                self._fast = FastStateReader.for_env(u)
                self._fast_scene = self._scene_builds
            # checked bit for bit against get_state_dict() at every episode start (~0.3 ms)
            if self._fast is not None and not self._fast.matches():
                self._fast = None
                self._fast_allowed = False  # this task's state needs get_state_dict(); stop trying
        if self.pose_bodies:
            from simreel.sim.describe import named_bodies

            missing = sorted(set(self.pose_bodies) - set(named_bodies(u)))
            if missing:
                bound.append(f"body poses not written: the rebuilt scene has no {', '.join(missing[:3])}")
                self.pose_bodies = []
        if self._contacts is not None:
            try:
                self._contacts.bind(u)
            except KeyError as e:
                bound.append(f"contacts not compared: the rebuilt scene has no body {e}")
                self._contacts = None
        done.limits += bound
        return done, bound

    def forget_scene(self) -> None:
        """Take the env's scene for unknown: the next reset rebuilds it (`reset_to_episode` with ``scene_seed=None``),
        which gives the state of an env fresh from ``gym.make`` again, history included: PhysX's CPU results depend on
        what the scene ran since it was built (`simreel.verdicts.scene_history`)."""
        self._scene_seed = None

    def scene_check(self, ep: EpisodeMeta) -> list[SceneDifference] | None:
        """Every difference between episode `ep`'s recorded scene fingerprint and the scene the env holds now (after
        `reset_for(ep)`); None when the recording has no fingerprint. The live fingerprint is taken once per scene
        build (~3 ms)."""
        from simreel.sim.fingerprint import apply_changes, scene_differences, scene_fingerprint

        if not self.meta.scene_fingerprint:
            return None
        if self._fingerprint is None or self._fingerprint[0] != self._scene_builds:
            self._fingerprint = (self._scene_builds, scene_fingerprint(self.u))
        recorded = apply_changes(self.meta.scene_fingerprint, ep.scene_changes)
        return scene_differences(recorded, self._fingerprint[1])

    def initial_state(self, ep: EpisodeMeta) -> dict[str, np.ndarray]:
        """The state right after resetting the env the way episode `ep` was reset (row 0 of a replay)."""
        self.reset_for(ep)
        return {k: np.array(v) for k, v in self._state().items()}

    def rerun_step_before(self, before: SceneBefore | None) -> None:
        """Re-run the step the recorder's scene simulated last before an episode's reset (`SceneBefore`; None:
        nothing to re-run), just before a restoring replay of that episode: its reset then keeps that step's
        contacts (a reset simulates nothing). For a scene then just built, the scene is rebuilt at the next reset if
        it has stepped since."""
        if before is None:
            return
        if before.episode is None:
            if self._stepped:
                self.forget_scene()
            return
        with task_code_errors():
            self._carried += self._reset_scene(before.episode)[1]
            self._check_layout()
            restore_state(self.u, before.state, elapsed_steps=before.step)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # an out-of-bounds action: the recording had it too
                self.u._step_action(self._actions(before.action))
        self._stepped = True


    def _start_unseeded(self, source: EpisodeRows, recorded: StepBlock) -> list[str]:
        """Start an episode without a seed where it began (`recorded`: its reset row). Where the recording holds the
        random generators its reset drew from (`EpisodeMeta.reset_generators`), the replay's reset drew from them
        too (`reset_for`): a reset that remade the recorded initial state bit for bit is kept, with everything PhysX
        and the controllers keep beside the state. Otherwise the recorded initial state is restored: the limit that
        says so, and why (none for a seeded episode, or a remade reset). `RecordingFileError` where the recording
        holds no states to start from: where the episode began is then unknown, and stepping from another start would
        judge another trajectory."""
        if source.meta.seed is not None and not source.meta.seed_unchecked:
            return []
        row = RecordedStates(recorded).row(0)
        if not row:
            raise RecordingFileError(getattr(source, "path", None) or "the recording",
                                     f"episode {source.meta.index}: {UNSEEDED_WITHOUT_STATES}: it cannot be replayed")
        if source.meta.seed_unchecked:
            return self._check_seed(source.meta.seed, row)
        if source.meta.reset_generators:
            differing = _differing_leaves(row, self._state())
            if not differing:
                return []
        restore_state(self.u, row, elapsed_steps=0)
        restored = ["actions replayed from the recorded initial state"]
        if not source.meta.reset_generators:
            return restored
        return [f"the reset from the recorded generator states did not remake the recorded initial state "
                f"({', '.join(differing[:3])} differ: the reset drew from something else too, or another engine "
                "replays it)", *restored]

    def _check_seed(self, seed: int | None, row: dict[str, np.ndarray]) -> list[str]:
        """Start an episode whose `seed` may be stale (``EpisodeMeta.seed_unchecked``), reset with it, where it began:
        a reset that remade the recorded initial state (`row`) bit for bit is kept; else that state is restored, and
        the limits say so, naming the stale seed."""
        differing = _differing_leaves(row, self._state())
        if not differing:
            return []
        restore_state(self.u, row, elapsed_steps=0)
        return [f"stale seed: a reset with episode_seed {seed} did not remake the recorded initial state "
                f"({', '.join(differing[:3])} differ: the episode was reset without a seed)",
                "actions replayed from the recorded initial state"]


    def _check_layout(self) -> None:
        if not self._layout_checked and self.meta.state_layout:  # a file without env_states has none to check
            check_rebuilt_layout(self.u, self.meta.env_id, self.meta.state_layout)
            self._layout_checked = True


def _differing_leaves(recorded: dict[str, np.ndarray], live: dict[str, np.ndarray]) -> list[str]:
    """The leaves of state row `recorded` that the `live` state does not hold bit for bit (in the recorded dtype)."""
    return [path for path, a in recorded.items()
            if path not in live or not np.array_equal(np.asarray(live[path], a.dtype).reshape(a.shape), a)]
