"""Built-in rig files (``NAME.toml``); their default plans ship with the app (:mod:`app.models`)."""
