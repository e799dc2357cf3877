"""The ``hydrolink`` command (placeholder until the CLI lands)."""


def main() -> None:
    raise SystemExit("hydrolink: CLI not assembled yet")
