"""The bottom layer every other package may import: errors, atomic writes, JSON, checks, figures,
random streams. It imports nothing of the project."""
