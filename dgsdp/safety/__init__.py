"""Reading files other people hand the project as data, never as code: checkpoints (:mod:`.checkpoint_file`), motion
pickles (:mod:`.safe_pickle`) and the bounded scan both go through (:mod:`.pickle_scan`)."""
