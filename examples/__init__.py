"""The scenario files and scripts of ``examples/``, installed with canstack as the package
``canstack_examples`` (``canstack examples`` lists and copies them). Nothing here is imported by
canstack itself: the files are read as package data."""
