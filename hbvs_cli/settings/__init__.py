"""What each command was asked to do: its options, each declared once (:mod:`.option`, :mod:`.commands`), and the
``--config`` file (:mod:`.config`). Above io (help texts name its topics and files), below what reads the options."""
