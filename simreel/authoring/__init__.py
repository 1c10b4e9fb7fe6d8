"""The SDK for task authors: make a ManiSkill task record-safe.

- `simreel.authoring.custom_state`: declare task state that the state dict must carry (`CustomStateMixin`).
- `simreel.authoring.heterogeneous`: a different object per sub-scene, merged and registered so the state layout
  does not depend on which objects were drawn or on ``num_envs``.

Neither imports mani_skill, sapien or torch until a helper is called.
"""
