"""Checks of the repository as a whole: the import rules, and the commands and options the docs name."""
