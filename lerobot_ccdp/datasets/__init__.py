"""Datasets: demonstration recording, recipe files and their command lines, atomic writing and ownership."""
