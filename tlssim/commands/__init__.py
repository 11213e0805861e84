"""Sub-commands of the ``tlssim`` console script (one module each)."""
