"""The polyscope viewer (side-by-side comparisons, marker dragging, playback).

Built in issue 7; this package exists so the layout and packaging are in place.
"""
