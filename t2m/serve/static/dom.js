// The page's elements by id (index.html names every element a module touches).

export const $ = (id) => document.getElementById(id);
