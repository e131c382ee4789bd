"""One module per ``d2slam`` subcommand. Each defines ``register(subparsers)`` that adds its parser and sets
``func`` (called with the parsed args; returns an exit code or None). Commands stay thin: they parse, call the
library, and print."""
