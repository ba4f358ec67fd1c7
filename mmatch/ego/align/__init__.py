"""Aligners: the transform between the two radars from the matched vehicles and the backgrounds."""
