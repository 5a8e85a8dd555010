"""Small helpers below every other layer (only :mod:`giwbc.errors` is lower): child processes."""
