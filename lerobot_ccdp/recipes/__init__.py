"""The jobs behind `datasets_recipes/`: demonstration recording (and, later, recovery synthesis)."""
