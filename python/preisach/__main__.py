"""``python -m preisach`` runs the CLI."""
from preisach.cli import main

raise SystemExit(main())
