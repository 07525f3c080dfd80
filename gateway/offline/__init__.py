"""Offline tools on recordings: interchange CSV, grid, replay, reports."""
