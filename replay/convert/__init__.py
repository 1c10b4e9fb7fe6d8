"""Conversion: a recording converted to another obs or control mode and verified (`convert`: `convert_recording`);
`control` maps actions between control modes, `tracking` measures how well a converted action tracks the original."""
