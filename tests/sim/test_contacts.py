"""`simreel.sim.contacts`: the `contacts` option in each form Python gives it, against a real env's bodies."""

from __future__ import annotations

import pytest

from simreel.errors import UsageError
from simreel.sim.contacts import contact_channels, contacts_spec
from simreel.sim.make import make_env

TAKES = ('give "auto", "none", or contact pairs as a string "panda/panda_leftfinger:cube,cube:table-workspace" or a '
         'list of "A:B" strings')


@pytest.fixture(scope="module")
def pushcube():
    env = make_env("PushCube-v1")
    env.reset(seed=0)
    yield env.unwrapped
    env.close()


@pytest.mark.parametrize("pairs", [["cube:table-workspace", "goal_region:cube"],
                                   ("cube:table-workspace", "goal_region:cube")], ids=["list", "tuple"])
def test_a_list_of_pairs_gives_the_channels_of_the_pairs_joined(pushcube, pairs):
    """A list was AttributeError: 'list' object has no attribute 'strip'."""
    assert contacts_spec(pairs) == "cube:table-workspace,goal_region:cube"
    assert contact_channels(pushcube, pairs) == contact_channels(pushcube, "cube:table-workspace,goal_region:cube")


@pytest.mark.parametrize("contacts", [123, ["cube:table-workspace", 5], {"cube": "table-workspace"}],
                         ids=["int", "list-with-int", "dict"])
def test_anything_else_is_one_usage_error_saying_what_contacts_takes(pushcube, contacts):
    with pytest.raises(UsageError) as refused:
        contact_channels(pushcube, contacts)
    assert str(refused.value) == f"contacts={contacts!r}: {TAKES}"


def test_a_string_and_none_are_kept_as_they_are():
    assert contacts_spec("auto") == "auto" and contacts_spec(None) is None and contacts_spec("") == ""
