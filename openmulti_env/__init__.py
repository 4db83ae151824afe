"""OpenMulti environment: the PettingZoo env, the simulated world it runs in, and the CLI."""
