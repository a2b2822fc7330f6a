"""Flight records: the MCAP recorder and the ``quadnav-review`` tool."""
