"""What a `RecordWrapper.reset` is asked, checked and read before the env resets: its options, the envs it resets
(`envs_to_reset`), its seeds (`check_seeds`; `episode_seeds`, each reset env's episode seed as the recording keeps
it), and whether it draws its episode from generators a replay must be given (`draws_from_generators`). A wrong
argument is a `UsageError` before anything changes, where ManiSkill would fail inside its reset or reset wrongly."""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from typing import Any

from simreel.errors import UsageError
from simreel.model.state_tree import to_numpy
from simreel.sim.seeds import SEED_LIMIT, is_seed

__all__ = ["reset_options", "envs_to_reset", "check_seeds", "episode_seeds", "draws_from_generators"]


def reset_options(options: Any) -> dict[str, Any]:
    """`reset()`'s options as a dict of its own (None: none); `UsageError` for anything but a dict."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise UsageError(f"reset(options={options!r}): give a dict of reset options, e.g. {{'env_idx': [0]}} or "
                         "{'reconfigure': True}")
    return dict(options)


def envs_to_reset(env_idx: Any, n: int) -> list[int]:
    """The envs of `n` a reset with ``options={"env_idx": env_idx}`` resets (None: all of them); `UsageError`, before
    anything changes, for what ManiSkill would fail on inside its reset (a single index, which it takes the
    ``len()`` of; an index out of range) or would reset wrongly (an env named twice)."""
    if env_idx is None:
        return list(range(n))
    named = to_numpy(env_idx)
    if named.ndim == 0:
        example = [int(env_idx)] if isinstance(env_idx, numbers.Integral) else [0]
        raise UsageError(f"reset(options={{'env_idx': {env_idx!r}}}): give a list of the envs to reset, from 0 to "
                         f"{n - 1}, e.g. {{'env_idx': {example}}} (ManiSkill takes no single index)")
    named = named.reshape(-1)
    if named.size and named.dtype.kind not in "iu":
        raise UsageError(f"reset(options={{'env_idx': ...}}) holds {named.dtype} values; give the indices of the "
                         f"envs to reset, from 0 to {n - 1}")
    idxs = [int(i) for i in named]
    if not idxs or len(set(idxs)) != len(idxs) or not all(0 <= i < n for i in idxs):
        raise UsageError(f"reset(options={{'env_idx': {idxs}}}): name each env to reset once, from 0 to "
                         f"{n - 1} (an env named twice would begin two episodes at once)")
    return idxs


def check_seeds(seed: Any, idxs: list[int], n: int) -> None:
    """Refuse, before anything changes, a seed ManiSkill would fail on inside its reset, once the episodes this
    reset ends were committed (anything but ints from 0 to 2**32 - 1: `is_seed`), and a seed list of another
    length than one seed, one per env (`n`), or one per env reset (`idxs`): ManiSkill 3.0.1 takes any list as the
    episode seeds of all its envs, so with another length no seed belongs to an env and the recording would lose
    its seed (`episode_seeds`)."""
    if seed is None:
        return
    seeds = _seed_list(seed)
    if seeds is None and not is_seed(seed):
        raise UsageError(f"reset(seed={seed!r}): ManiSkill takes seeds from 0 to {SEED_LIMIT - 1}; give one such "
                         f"int, or a list of one per env ({n})")
    bad = [s for s in seeds or () if not is_seed(s)]
    if bad:
        raise UsageError(f"reset(seed=...) holds {bad[0]!r}: ManiSkill takes seeds from 0 to {SEED_LIMIT - 1}; "
                         f"give ints in that range, one seed or a list of one per env ({n})")
    count = 1 if seeds is None else len(seeds)
    if count not in (1, n, len(idxs)):
        per_reset = f" or one per env reset ({len(idxs)})" if len(idxs) != n else ""
        raise UsageError(f"reset(seed=...) got {count} seeds for {n} env(s); give one seed, or a list of one "
                         f"seed per env ({n}){per_reset}")


def episode_seeds(u: Any, seed: Any, idxs: list[int]) -> list[int | None]:
    """The episode seed of each env of ManiSkill env `u` the reset with `seed` reset (`idxs`), or None where the
    reset was not reproducible from a seed.

    ManiSkill 3.0.1 leaves `_episode_seed` stale after `reset(seed=None)` (the episode is drawn from
    the global RNG instead) and, for a partial reset with a seed list, replaces the whole array by
    that list, one seed per reset env in order.
    """
    if seed is None and not getattr(u, "_enhanced_determinism", False):
        return [None] * len(idxs)
    drawn = to_numpy(u._episode_seed).reshape(-1)
    if len(drawn) == int(u.num_envs):
        return [int(drawn[i]) for i in idxs]
    if len(drawn) == len(idxs):
        return [int(x) for x in drawn]
    return [None] * len(idxs)


def draws_from_generators(u: Any, seed: Any) -> bool:
    """Whether a reset of ManiSkill env `u` with `seed` draws its episode from generators that are not reseeded, in
    a way a replay can repeat once it has their states (`simreel.sim.generators`): one without a seed, enhanced
    determinism off, in a one-env recording (a replay resets one env at a time; with several, one draw serves them
    all)."""
    return seed is None and int(u.num_envs) == 1 and not getattr(u, "_enhanced_determinism", False)


def remade_by_replay(u: Any, generators: dict[str, str]) -> bool:
    """Whether a replay remakes the reset of an unseeded episode of ManiSkill env `u`, whose reset consumed
    `generators` (`simreel.sim.generators.consumed_generators`): on the CPU sim with one env, with their states
    captured (measured exact). Not with several envs (one draw serves them all; none is captured), and not taken to
    on the GPU sim (its results are deterministic only for the same batch, and its exactness from captured states
    was not measured); a replay then starts from the recorded initial state."""
    return bool(generators) and not bool(getattr(u, "gpu_sim_enabled", False))  # (captured only with one env)


def unseeded_warning(u: Any) -> str:
    """What the recorder says, once, at the first unseeded reset of `u` that no replay remakes."""
    where = f"{int(u.num_envs)} envs" if int(u.num_envs) > 1 else "the GPU sim"
    return (f"simreel: reset() without a seed on {where}: a replay cannot remake these resets (their random draws "
            "are not captured), so it starts each such episode from its recorded initial state, which the state "
            "dict holds only in part (PhysX keeps more): expect within_tolerance at best, not exact. Give "
            "reset(seed=...) one seed per env to make them exact (`simreel inspect` counts them)")


def _seed_list(seed: Any) -> list[Any] | None:
    """The seeds of `reset(seed=...)` given as a list, a tuple, an array or a tensor (one value each), or None for
    anything else, a single seed or not one at all."""
    if isinstance(seed, (list, tuple)):
        return list(seed)
    if hasattr(seed, "dtype") and hasattr(seed, "shape"):
        return to_numpy(seed).reshape(-1).tolist()
    return None
