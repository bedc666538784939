"""File primitives every layer may use: atomic files and sets of files (``files``,
``rundir``), figures (``figures``) and the environment a result was computed in
(``environment``). Above the configuration types (``problem``) only."""
