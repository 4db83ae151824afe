"""Open-vocabulary front end: segmenters, captioner, text and image-text encoders, error model, code book.

No PettingZoo, Gymnasium, pyrender or ``openmulti_env`` imports here.
"""

from mapping.perception.codebook import CodeBook, CodeBookEntry, CodeBookError
from mapping.perception.text_encoder import TEXT_FEATURE_DIM, TextEncoder, TextEncoderError, shared_text_encoder
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult, InstanceInfo, Segment

__all__ = ["AgentInstance", "CodeBook", "CodeBookEntry", "CodeBookError", "FusionResult", "FrameSegmentation", "InstanceInfo", "Segment", "TEXT_FEATURE_DIM", "TextEncoder",
           "TextEncoderError", "shared_text_encoder"]
