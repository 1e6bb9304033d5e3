"""Small examples written against odolab.api only (run from the repository root)."""
