"""Ego side: which vehicles both views show (matchers) and the transform between the radars (aligners).

Matchers and aligners are looked up by name (`mmatch eval --matcher NAME --aligner NAME`);
see `registry`. References that must always exist: matcher `oracle` and aligner
`centroid-icp`.
"""
