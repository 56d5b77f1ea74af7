// bindings: written below
