"""Recording: layout (entity paths, blueprint), writing, reading back."""
