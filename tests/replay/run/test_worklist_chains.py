"""How a run's items are grouped for its processes (`simreel.replay.run.worklist.chain_groups`): the episodes of one scene
chain stay together in their order, also where a recording with parallel envs interleaves its sub-scenes' chains, and
items without a chain are spread one by one; an actions run's work list names each episode's chain; a pool
(`run_pool`, real worker processes) runs each group in one process, in order."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

from simreel.cli.main import main
from simreel.replay.run.job import EpisodeResult
from simreel.replay.run.pool import run_pool
from simreel.replay.run.worklist import WorkItem, build_worklist, chain_groups


def _item(index: int, chain: str | None) -> WorkItem:
    return WorkItem("key", "/data/a.h5", index, 10, chain)


def test_interleaved_chains_are_grouped_where_each_starts():
    items = [_item(0, "a#0"), _item(1, "a#1"), _item(2, "a#0"), _item(3, "a#1"), _item(4, "a#4")]
    assert [[i.index for i in g] for g in chain_groups(items)] == [[0, 2], [1, 3], [4]]


def test_items_without_a_chain_are_each_a_group():
    assert [[i.index for i in g] for g in chain_groups([_item(0, None), _item(1, None)])] == [[0], [1]]


def test_an_actions_work_list_names_each_episodes_chain_and_a_step_one_none(tmp_path, capsys):
    path = tmp_path / "rf2.h5"  # ManiSkill rebuilds the scene at episodes 1 and 3 (its reconfiguration counter)
    assert main(["record", "PickCube-v1", "-o", str(path), "-n", "4", "--max-steps", "5", "--render-backend", "none",
                 "-q", "--env-kwargs", '{"reconfiguration_freq": 2}']) == 0
    actions = build_worklist([path], chains=True).items
    assert [item.chain for item in actions] == [f"{path}#0", f"{path}#1", f"{path}#1", f"{path}#3"]
    assert {item.chain for item in build_worklist([path], restores="--mode step").items} == {None}


@dataclass(frozen=True)
class _PidJob:
    """A job for `run_pool` whose worker takes a while per item and answers with the pid that ran it."""

    seconds: float = 0.3

    def open_worker(self) -> _PidWorker:
        return _PidWorker(self)


class _PidWorker:
    def __init__(self, job: _PidJob) -> None:
        self.job = job

    def run(self, item: WorkItem) -> EpisodeResult:
        time.sleep(self.job.seconds)
        return EpisodeResult(item, worker=str(os.getpid()))


def test_a_pool_runs_each_chain_in_one_process_in_order():
    items = [_item(i, f"a#{i // 3}") for i in range(12)]  # four chains of three
    results: list[EpisodeResult] = []
    run_pool(_PidWorker(_PidJob()), items, 3, results.append)
    assert sorted(r.item.index for r in results) == list(range(12))
    for chain in range(4):
        ran = [r for r in results if r.item.chain == f"a#{chain}"]
        assert len({r.worker for r in ran}) == 1
        assert [r.item.index for r in ran] == [3 * chain, 3 * chain + 1, 3 * chain + 2]
    assert len({r.worker for r in results}) >= 2
