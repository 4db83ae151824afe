"""The model of one agent's map (sec. III-D/E): per-instance fields and their parameters, ray sampling and
rendering, the data loss, keyframes, the optimiser, the agent's mapper and the fleet that batches mappers;
MACIM's scene SDF for the published global baseline. ``mapping.team`` builds teams of these mappers."""
