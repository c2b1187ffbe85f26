"""The levitated ball's effect library: one module per effect (``MODULES``)."""
MODULES = []
