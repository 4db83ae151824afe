"""The paper's experiments as commands (``openmulti reproduce``).

    methods   every baseline and ablation as a named preset of the same team options
    tables    which runs each table needs, and the paper's figures beside them
    runner    keyed, atomic, resumable runs (one ``openmulti_env.runs.run.run`` each) with a progress bar
    writers   DIR/T.json, DIR/T.md (means over seeds with their spread) and DIR/T.png
"""
