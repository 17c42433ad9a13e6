"""What the commands write: one module per command output (chest plans, robot plans, tissue
plans, the collision table)."""
