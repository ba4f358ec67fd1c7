"""Matchers: which vehicles of the two views are the same (looked up by name in `ego.registry`)."""
