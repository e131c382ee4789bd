"""Frozen reference: ``d2slam/dynamics`` as of commit 89252f3 (before the speed work), verbatim except for relative
imports. ``tests/test_dynamics_equivalence.py`` checks that the current, faster modules give *identical* outputs.
Do not edit (except to delete it together with that test)."""
