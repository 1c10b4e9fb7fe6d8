"""Heterogeneous objects: merged views in the registry, state shapes that do not depend on the draw."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import pytest
import torch

from simreel.authoring.heterogeneous import HeterogeneousBuildError, merge_articulations
from simreel.errors import SimreelError
from simreel.sim.render_device import configure_vulkan

configure_vulkan()  # the project lavapipe, before sapien creates a device (as make_env does)


def test_helpers_import_without_torch_or_mani_skill():
    code = (
        "import sys, simreel.authoring.custom_state, simreel.authoring.heterogeneous; "
        "print(sorted(m for m in ('torch', 'mani_skill', 'sapien') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# --------------------------------------------------------------------------------------------------
# merge_articulations refuses what would make the state depend on the draw (checked before any merge)
# --------------------------------------------------------------------------------------------------
def _part(name: str, dof: int, links=("body", "handle")):
    return SimpleNamespace(name=name, _objs=[SimpleNamespace(dof=dof)], links_map={k: None for k in links})


def test_different_dof_without_state_dof_is_refused():
    parts = [_part("cab-0", 1), _part("cab-1", 3)]
    with pytest.raises(HeterogeneousBuildError) as e:
        merge_articulations(parts, name="cab", state_dof=None)
    assert str(e.value) == (
        "parts of 'cab' have DOF [1, 3]: the state shape would depend on which parts were drawn; "
        "pass state_dof=<largest DOF this task can build> (e.g. 3 or more)"
    )
    assert isinstance(e.value, SimreelError)


def test_a_part_over_state_dof_is_refused():
    with pytest.raises(HeterogeneousBuildError) as e:
        merge_articulations([_part("cab-0", 4)], name="cab", state_dof=3)
    assert str(e.value) == (
        "a part of 'cab' has 4 DOF, more than state_dof=3; raise state_dof to the largest DOF the task can build"
    )


def test_a_merged_link_every_part_must_have():
    parts = [_part("cab-0", 1), _part("cab-1", 2, links=("body", "knob"))]
    with pytest.raises(HeterogeneousBuildError) as e:
        merge_articulations(parts, name="cab", state_dof=3, merged_links=["handle"])
    assert str(e.value) == (
        "cannot merge link 'handle' of 'cab': parts ['cab-1'] have no such link "
        "(they have ['body', 'handle']); give the link that name in every part"
    )


def test_no_parts_is_refused():
    with pytest.raises(HeterogeneousBuildError, match="got no parts"):
        merge_articulations([], name="cab", state_dof=3)


# --------------------------------------------------------------------------------------------------
# On the real heterogeneous tasks
# --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def make():
    import simreel.tasks  # noqa: F401  (registers the tasks)
    from simreel.sim.make import make_env

    envs = {}

    def _make(env_id):
        if env_id not in envs:
            envs[env_id] = make_env(env_id)  # the render device this machine has (state obs)
        return envs[env_id]

    yield _make
    for env in envs.values():
        env.close()


def test_registry_holds_the_merged_actor_not_its_parts(make):
    env = make("SimreelHeteroPick-v1")
    env.reset(seed=0)
    scene = env.unwrapped.scene
    registry = scene.state_dict_registry
    assert "object" in registry.actors and "object-0" not in registry.actors
    assert registry.actors["object"] is scene.actor_views["object"] is env.unwrapped.obj
    assert "object-0" in scene.actors  # ManiSkill still manages the part itself
    assert env.unwrapped.get_state_dict()["actors"]["object"].shape == (1, 13)


def test_registry_holds_the_merged_cabinet_padded_to_three_dof(make):
    env = make("SimreelHeteroDrawer-v1")
    u = env.unwrapped
    dofs = set()
    for seed in (0, 1, 3):  # cabinets of 1, 2 and 3 joints
        env.reset(seed=seed)
        dofs.add(u.cabinet_dofs()[0])
        registry = u.scene.state_dict_registry
        assert sorted(registry.articulations) == ["cabinet", "panda"]
        assert registry.articulations["cabinet"] is u.scene.articulation_views["cabinet"] is u.cabinet
        assert u.get_state_dict()["articulations"]["cabinet"].shape == (1, 13 + 2 * 3)
        assert u.cabinet.get_qpos().shape == (1, u.cabinet_dofs()[0])
    assert dofs == {1, 2, 3}


def test_merged_handle_link_gives_the_joint_position(make):
    env = make("SimreelHeteroDrawer-v1")
    u = env.unwrapped
    env.reset(seed=6)  # joints (drawer, knob, drawer), the target is the second drawer: joint 2
    assert u.cabinet_specs[0].joints == ("drawer", "knob", "drawer")
    assert u.cabinet.links_map["handle"] is u.handle
    assert [link.name for link in u.cabinet.links] == ["body", "handle"]
    u.cabinet.set_qpos(torch.tensor([[0.02, 0.5, 0.07]]))
    assert u.handle.joint.qpos.shape == (1,)
    assert u.handle.joint.qpos.item() == pytest.approx(0.07)


def test_padded_state_round_trips_through_set_state_dict(make):
    env = make("SimreelHeteroDrawer-v1")
    u = env.unwrapped
    env.reset(seed=1)  # a 2-joint cabinet: qpos and qvel padded by one zero each
    u.cabinet.set_qpos(torch.tensor([[0.05, 0.3]]))
    state = u.get_state_dict()
    row = state["articulations"]["cabinet"][0]
    assert row[13:16].tolist() == pytest.approx([0.05, 0.3, 0.0])
    assert row[18].item() == 0.0
    u.cabinet.set_qpos(torch.zeros(1, 2))
    u.set_state_dict(state)
    assert u.cabinet.get_qpos()[0].tolist() == pytest.approx([0.05, 0.3])
    assert torch.allclose(
        u.get_state_dict()["articulations"]["cabinet"], state["articulations"]["cabinet"], atol=1e-6
    )
    u.set_state(u.get_state())  # the flat vector goes through the same padding
    assert u.handle.joint.qpos.item() == pytest.approx(0.05)
