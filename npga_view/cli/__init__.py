"""The `npga-view` command: `main` parses the subcommand (the viewer by default, info, render, bench, export)."""
