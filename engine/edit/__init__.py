"""Edits applied from an export alone: the edit equations, render, project-frame and preview."""
