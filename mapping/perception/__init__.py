"""Open-vocabulary front end: segmenters, captioner, text and image-text encoders, error model, code book,
the categories' vocabulary.

No PettingZoo, Gymnasium, pyrender or ``openmulti_env`` imports here.
"""

from mapping.perception.codebook import CodeBook, CodeBookEntry, CodeBookError
from mapping.perception.text_encoder import TEXT_FEATURE_DIM, TextEncoder, TextEncoderError, shared_text_encoder
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult, InstanceInfo, Segment
from mapping.perception.vocabulary import CATEGORY_PROMPT, Vocabulary, category_prompts

__all__ = ["AgentInstance", "CodeBook", "CodeBookEntry", "CodeBookError", "FusionResult", "FrameSegmentation", "InstanceInfo", "Segment", "TEXT_FEATURE_DIM", "TextEncoder",
           "TextEncoderError", "shared_text_encoder", "CATEGORY_PROMPT", "Vocabulary", "category_prompts"]
from mapping.perception.captioner import Captioner, TemplateCaptioner, wrong_category
from mapping.perception.errors import ErrorPlan, SegmentationErrorConfig, plan_errors
from mapping.perception.front_end import encode_segments
from mapping.perception.image_encoder import (ImageEncoderError, ImageTextEncoder, OpenClipEncoder, VisualFeatureNotice,
                                              crop_for_mask, load_image_encoder)
from mapping.perception.segmenter import DatasetMaskSegmenter, OracleSegmenter, Segmenter

__all__ += ["Captioner", "DatasetMaskSegmenter", "ErrorPlan", "ImageEncoderError", "ImageTextEncoder", "OpenClipEncoder",
            "OracleSegmenter", "SegmentationErrorConfig", "Segmenter", "TemplateCaptioner", "VisualFeatureNotice",
            "crop_for_mask", "encode_segments", "load_image_encoder", "plan_errors", "wrong_category"]
