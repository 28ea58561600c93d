from phonepose.cli import main

main()
