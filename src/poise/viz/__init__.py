"""Pictures of results files: ``poise plot`` (plot) and ``poise animate`` (animate); matplotlib is
imported only here."""
