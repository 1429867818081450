"""Sim-to-real gap diagnosis (issue #6): where the gap lies, which unmodelled effect causes it,
and how far it shrinks once that effect is modelled.

    python -m neck_env.gap DATASET_DIR --json REPORT.json

See ``docs/gap.md`` for the method; ``neck_env.gap.synthetic`` writes synthetic "real" datasets.
"""
