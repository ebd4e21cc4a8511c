"""Input stage: recordings and field logs in, validated :class:`~discrepancy.data.episode.EpisodeData` out."""
