"""The plan preview's colours, shared by its static scene and the strokes each plan adds: one place,
so the picture stays one palette (and the violation red the only saturated red in it)."""

from __future__ import annotations

WHITE = (255, 255, 255)
FRAME = (165, 165, 165)
TEXT = (40, 40, 40)
WORKSPACE = (50, 80, 160)
KEEP_OUT_FILL = (230, 70, 70, 70)
KEEP_OUT_EDGE = (170, 50, 50)
KEEP_OUT_TEXT = (130, 25, 25)
LINK_FILL = (228, 228, 228)
LINK_EDGE = (160, 160, 160)
LINK_GOAL = (95, 95, 95)
PATH = (235, 140, 0)
START = (0, 165, 60)
GOAL = (0, 80, 230)
BASE = (30, 30, 30)
VIOLATION = (255, 0, 0)  # the only saturated red in the picture
STATUS_COLOUR = {"ok": (0, 125, 45), "needs_approval": (185, 115, 0), "rejected": (150, 0, 0)}
SEPARATOR = (215, 215, 215)
#: the swept links' colours, by their index in the sweep's masks (0 is a pixel the sweep left alone):
#: fill, outlines of the earlier poses, the goal pose's outline
SWEEP_COLOURS = (LINK_FILL, LINK_EDGE, LINK_GOAL)
