"""Sub-commands of the ``kms2pin`` CLI; each module defines NAME, HELP, add_arguments, run."""
