from swarmraft.cli import main

main()
