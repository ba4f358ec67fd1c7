"""`mmatch report`: the paper's comparison on one folder of scene files, in one run.

methods.py names the compared methods (a matcher and an aligner each); run.py evaluates
them all through `mmatch.evaluate` on the same files, interleaved scene by scene so that a
busy machine slows every method alike; tables.py derives the table figures and the
breakdowns by scene (co-visible vehicles, vehicles per view, road, driving direction) and
writes the markdown; plots.py draws the figures (`plots` extra).
"""
