"""``python -m neck_env.gap DATASET_DIR --json REPORT.json``"""

from .cli import main

raise SystemExit(main())
