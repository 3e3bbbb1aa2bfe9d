"""An example whiskerbench plugin package (docs/plugins.md): a marker detector and a branch
finder that know nothing of whiskerbench beyond the two signatures."""
