"""Ray sampling and volume rendering: small pure functions over flat tensors."""
