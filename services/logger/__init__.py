"""Logger service: every bus message recorded with Rerun (the only rerun importer)."""
