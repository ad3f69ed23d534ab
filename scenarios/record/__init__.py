"""What a run leaves on disk: the Rerun recording (``recording``) with its entity tree and
views (``viewer``), state panel (``panel``) and plots (``plots``); reading a recording back
(``reader``); and writing every output file whole (``outputs``)."""
