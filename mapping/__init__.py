"""OpenMulti mapping: the learner (no PettingZoo, Gymnasium or pyrender here)."""
