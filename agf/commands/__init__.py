"""The implementations of the ``agf`` sub-commands that are logic of this package: they call the
vision, shape DESIGN.md's JSON contract and draw the overlays (the vision returns what it found and
never draws)."""
