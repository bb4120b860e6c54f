"""Command-line entry points, kept light: ``--help`` answers before torch or a node is loaded."""
