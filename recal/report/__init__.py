"""HTML and matplotlib reports of the command line and the service (the only part of recal that draws or builds documents; the numerics never import it)."""
