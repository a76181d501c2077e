"""Built-in rig files (``NAME.toml``) and their default plans (``NAME.plan.toml``)."""
