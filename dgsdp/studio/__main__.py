"""``python -m dgsdp.studio``: start the dance studio (see ``--help``)."""

from dgsdp.studio import main

if __name__ == "__main__":
    main()
