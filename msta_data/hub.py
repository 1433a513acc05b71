"""Transitional: the hub client was split by job; import from the module that holds a name.

=====================  ==================================================================
module                 names
=====================  ==================================================================
msta_data.hub_ids      HubError, HubIntegrityError, HubId, parse_hub_id, is_hub_id, hub_api
msta_data.hub_cards    CardInfo, model_card, dataset_card, card_metadata, card_metrics
msta_data.hub_push     push, push_dataset, PICKLE_SUFFIXES
msta_data.hub_pull     resolve, pull, materialize, default_cache_dir
msta_data.hub_versions versions, Version, RepoVersions
=====================  ==================================================================

This module only re-exports those names for callers not yet moved (eval/demo.py,
eval/evaluate.py); it is deleted once they import from the modules above.
"""

from msta_data.hub_cards import CardInfo, card_metadata, card_metrics, dataset_card, model_card
from msta_data.hub_ids import HubError, HubId, HubIntegrityError, hub_api, is_hub_id, parse_hub_id
from msta_data.hub_pull import default_cache_dir, materialize, pull, resolve
from msta_data.hub_push import PICKLE_SUFFIXES, push, push_dataset
from msta_data.hub_versions import RepoVersions, Version, versions

__all__ = [
    "PICKLE_SUFFIXES", "CardInfo", "HubError", "HubId", "HubIntegrityError", "RepoVersions",
    "Version", "card_metadata", "card_metrics", "dataset_card", "default_cache_dir",
    "hub_api", "is_hub_id", "materialize", "model_card", "parse_hub_id", "pull", "push",
    "push_dataset", "resolve", "versions",
]
